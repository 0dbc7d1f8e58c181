"""Operator props (``tracker.fitting.props``): parsing, masks, the fit's limit and its Jacobian."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.fitting.props import PropBox, PropError, PropPenalty, parse_prop, prop_masks, prop_rays, rays_meet_capsules
from tracker.synthetic.scene import ring_cameras


def test_parse_and_validate():
    box = parse_prop(" 0.2, -0.1,0, -0.3,0.5,0.45 ")
    assert np.allclose(box.lo, [-0.3, -0.1, 0.0]) and np.allclose(box.hi, [0.2, 0.5, 0.45])
    for bad in ["1,2,3", "a,b,c,d,e,f", "0,0,0,0,1,1", "0,0,0,11,1,1", "0,0,0,1,1,1e9"]:
        with pytest.raises(PropError):
            parse_prop(bad)
    with pytest.raises(PropError, match="session.toml"):
        PropBox.from_values([0, 0, 0, 1, 1, True], where="session.toml [[prop]]")


def test_signed_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    box = PropBox.from_values([-0.2, -0.3, 0.0, 0.3, 0.2, 0.5])
    X = rng.uniform(-0.6, 0.8, size=(500, 3))
    d, g = box.signed_distance(X)
    inside = np.all((X > box.lo) & (X < box.hi), axis=1)
    assert np.all((d < 0) == inside)
    outside = ~inside
    closest = np.clip(X, box.lo, box.hi)
    assert np.allclose(d[outside], np.linalg.norm(X - closest, axis=1)[outside])
    assert np.allclose(-d[inside], np.min(np.concatenate([X - box.lo, box.hi - X], axis=1), axis=1)[inside])
    # the gradient is the derivative of the distance (away from the box's medial planes and edges)
    h = 1e-6
    for axis in range(3):
        e = np.zeros(3)
        e[axis] = h
        fd = (box.signed_distance(X + e)[0] - box.signed_distance(X - e)[0]) / (2 * h)
        smooth = np.abs(fd - g[:, axis]) < 1e-4
        assert smooth.mean() > 0.97


def test_masks_cover_the_projected_box():
    cams = ring_cameras(4, size=(160, 120))
    box = PropBox.from_values([-0.2, -0.2, 0.0, 0.2, 0.2, 0.45])
    masks = prop_masks(cams, [box])
    for cam in cams:
        uv = np.round(cam.project(np.array([[0.0, 0.0, 0.2]]))[0]).astype(int)
        assert masks[cam.name][uv[1], uv[0]]
        assert 0 < masks[cam.name].mean() < 0.5
    # a box around a camera has no bounded projection there: left out of that camera's mask
    around = PropBox.from_values(list(cams[0].center - 0.5) + list(cams[0].center + 0.5))
    masks = prop_masks(cams, [around])
    assert not masks[cams[0].name].any()


def test_penalty_jacobian_matches_finite_differences():
    model = load_model("knossow40")
    rng = np.random.default_rng(11)
    pen = PropPenalty([PropBox.from_values([-0.3, -0.3, 0.0, 0.3, 0.3, 1.0])], weight=100.0)
    checked = 0
    for _ in range(5):
        p = model.clamp(model.zero() + rng.normal(0, 0.15, model.n_params))
        p[:3] += rng.normal(0, 0.05, 3)
        r, J = pen.residuals(model, p, jacobian=True)
        assert r.shape == (J.shape[0],) and J.shape[1] == model.n_params
        assert np.all(r >= 0) and np.any(r > 0)  # the standing body stands in the box
        h = 1e-6
        fd = np.zeros_like(J)
        for k in range(model.n_params):
            e = np.zeros(model.n_params)
            e[k] = h
            fd[:, k] = (pen.residuals(model, p + e)[0] - pen.residuals(model, p - e)[0]) / (2 * h)
        # rows at a kink (a face switch or the box's edge) are not differentiable there
        good = np.all(np.abs(fd - J) < 1e-3 * (1 + np.abs(J)), axis=1)
        assert good.mean() > 0.9
        checked += int(good.sum())
    assert checked > 0


def test_penalty_is_zero_away_from_the_box_and_pushes_out():
    model = load_model("knossow40")
    p = model.zero()
    far = PropPenalty([PropBox.from_values([3.0, 3.0, 0.0, 3.5, 3.5, 0.5])])
    assert not np.any(far.residuals(model, p)[0])
    # a box at the right leg: the gradient step moves the leg out (the residuals fall)
    pose = forward(model, p)
    knee = pose.translation[model.part_names.index(next(n for n in model.part_names if "shank" in n or "calf" in n))]
    box = PropBox.from_values(list(knee - 0.05) + list(knee + 0.05))
    pen = PropPenalty([box])
    r, J = pen.residuals(model, p, jacobian=True)
    assert r.sum() > 0
    step = -np.linalg.lstsq(J, r, rcond=None)[0]
    r2 = pen.residuals(model, p + 0.3 * step)[0]
    assert r2.sum() < r.sum()


def test_session_prop_tables_validated(tmp_path, rng):
    from capture.session import SessionError, load_session
    from tests.support.sessions import make_session

    make_session(tmp_path, rng, n_frames=2)
    path = tmp_path / "session.toml"
    text = path.read_text()
    path.write_text(text + "\n[[prop]]\nbox = [0.2, 0.1, 0.0, -0.3, 0.6, 0.46]\n")
    session = load_session(tmp_path)
    assert session.props == ((-0.3, 0.1, 0.0, 0.2, 0.6, 0.46),)
    assert np.allclose(PropBox.from_values(session.props[0]).hi, [0.2, 0.6, 0.46])
    for bad, needle in [("[0, 0, 0, 1, 1]", "expected"), ("[0, 0, 0, 1, 1, 0]", "side"),
                        ('[0, 0, 0, 1, 1, "a"]', "expected"), ("[0, 0, 0, 1e3, 1, 1]", "within")]:
        path.write_text(text + f"\n[[prop]]\nbox = {bad}\n")
        with pytest.raises(SessionError, match=needle) as info:
            load_session(tmp_path)
        assert "session.toml" in str(info.value) and "prop" in str(info.value)


def _seated_scene(seed: int):
    """The cone model seated (``seated_params``) with a box under its thighs, 4 ring cameras:
    cameras, silhouettes (body and box), the body's projection grown by 2 px, joint centres, box."""
    import cv2

    from tracker.body.kinematics import joint_centres
    from tracker.imaging.render import render_label_images
    from tracker.search.seated import seated_params

    model = load_model("knossow40")
    rng = np.random.default_rng(seed)
    p = seated_params(model)
    pose = forward(model, p)
    jc = joint_centres(model, pose)
    p[2] -= min(jc["left_ankle"][2], jc["right_ankle"][2]) - 0.08  # feet on the floor
    p[:2] += rng.uniform(-0.3, 0.3, 2)
    pose = forward(model, p)
    jc = joint_centres(model, pose)
    hips = 0.5 * (jc["left_hip"] + jc["right_hip"])
    knees = 0.5 * (jc["left_knee"] + jc["right_knee"])
    top = hips[2] - 0.12
    box = PropBox.from_values([hips[0] - 0.2, hips[1] - 0.22, 0.0, knees[0] - 0.12, hips[1] + 0.22, top])
    cams = ring_cameras(4, size=(320, 240))
    labels = render_label_images(model, pose, cams)
    boxes = prop_masks(cams, [box])
    sils, explained = {}, {}
    for cam, lab in zip(cams, labels):
        body = (lab >= 0).astype(np.uint8)
        sils[cam.name] = (body > 0) | boxes[cam.name]
        explained[cam.name] = cv2.dilate(body, np.ones((5, 5), np.uint8)) > 0
    return model, p, cams, sils, explained, jc, box


@pytest.mark.parametrize("seed", [0, 1])
def test_seat_box_learns_the_seat_under_a_seated_body(seed):
    from tracker.fitting.props import seat_box

    model, p, cams, sils, explained, jc, box = _seated_scene(seed)
    learned = seat_box(cams, sils, explained, jc)
    assert learned is not None
    inter = np.prod(np.clip(np.minimum(learned.hi, box.hi) - np.maximum(learned.lo, box.lo), 0, None))
    union = np.prod(learned.hi - learned.lo) + np.prod(box.hi - box.lo) - inter
    assert inter / union > 0.5, (learned.lo, learned.hi, box.lo, box.hi)
    # the learned box keeps the body out: the seated pose itself intrudes only a little (the
    # pelvis may rest on it) while a pose with the thighs pushed into the box is penalised more
    pen = PropPenalty([learned])
    assert pen.residuals(model, p)[0].sum() < pen.residuals(model, p - np.eye(model.n_params)[2] * 0.1)[0].sum()


def test_seat_box_is_none_for_a_standing_body():
    from tracker.body.kinematics import joint_centres
    from tracker.fitting.props import seat_box

    model, p, cams, sils, explained, _, _ = _seated_scene(2)
    standing = joint_centres(model, forward(model, model.zero()))
    assert seat_box(cams, sils, explained, standing) is None


def test_track_cli_takes_props_and_names_a_bad_one(tmp_path, capsys):
    from service.cli import main
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.synth import bundled_motion

    root = make_synthetic_session(bundled_motion("scaled_131_03"), tmp_path / "hop", cameras=4, size=(160, 120),
                                  frames=3, n_background=4, seed=3)
    out, gt = tmp_path / "p.jsonl", str(root / "ground_truth.jsonl")
    assert main(["track", str(root), "--out", str(out), "--initial-pose", gt, "--prop", "1,2,3"]) == 2
    assert "--prop" in capsys.readouterr().err and not out.exists()
    (root / "session.toml").write_text((root / "session.toml").read_text() + "\n[[prop]]\nbox = [0, 0, 0, 1, 1]\n")
    assert main(["track", str(root), "--out", str(out), "--initial-pose", gt]) == 2
    err = capsys.readouterr().err
    assert "session.toml" in err and "prop" in err
    # a valid box far from the subject: tracked as before, three records
    (root / "session.toml").write_text((root / "session.toml").read_text().replace("box = [0, 0, 0, 1, 1]",
                                                                                   "box = [5, 5, 0, 5.5, 5.5, 0.5]"))
    assert main(["track", str(root), "--out", str(out), "--initial-pose", gt, "--prop=-6,-6,0,-5.5,-5.5,0.4"]) == 0
    assert len(out.read_text().splitlines()) == 3


def test_prop_rays_enter_the_box_where_brute_force_does():
    cams = ring_cameras(3, size=(80, 60))
    boxes = [PropBox.from_values([-0.2, -0.2, 0.0, 0.2, 0.2, 0.45]),
             PropBox.from_values([-0.25, 0.1, 0.45, -0.15, 0.2, 0.9])]
    rays = prop_rays(cams, boxes, prop_masks(cams, boxes))
    steps = np.linspace(0.0, 10.0, 20001)  # 0.5 mm along each ray
    for cam in cams:
        r = rays[cam.name]
        assert len(r.pixels) > 50 and np.allclose(r.origin, cam.center)
        # each ray's direction goes through its pixel
        assert np.allclose(cam.project(r.origin + r.directions), r.pixels[:, ::-1], atol=1e-6)
        pick = np.random.default_rng(0).choice(len(r.pixels), 60, replace=False)
        for i in pick:
            X = r.origin + steps[:, None] * r.directions[i]
            inside = np.zeros(len(steps), bool)
            for box in boxes:
                inside |= np.all((X >= box.lo) & (X <= box.hi), axis=1)
            if inside.any():
                assert abs(steps[np.argmax(inside)] - r.entry[i]) < 1e-3
            else:
                assert not np.isfinite(r.entry[i]) or r.entry[i] == pytest.approx(steps[-1], abs=1e-3)


def test_rays_meet_capsules_matches_sampled_distance():
    rng = np.random.default_rng(5)
    n, m = 300, 4
    origin = rng.normal(scale=0.2, size=3)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    length = rng.uniform(-0.5, 3.0, size=n)
    a, b = rng.uniform(-1.0, 1.0, size=(m, 3)), rng.uniform(-1.0, 1.0, size=(m, 3))
    b[0] = a[0]  # a degenerate axis: a sphere
    radius = rng.uniform(0.1, 0.6, size=m)
    got = rays_meet_capsules(origin, d, length, a, b, radius)
    s = np.linspace(0.0, 1.0, 1501)
    t = np.linspace(0.0, 1.0, 301)
    decided = 0
    for i in range(n):
        if length[i] <= 0:
            assert not got[i]
            continue
        P = origin + (s * length[i])[:, None] * d[i]                   # (S, 3)
        Q = a[:, None] + t[None, :, None] * (b - a)[:, None]            # (m, T, 3)
        gap = np.linalg.norm(P[None, :, None] - Q[:, None], axis=3).min(axis=(1, 2)) - radius
        if np.all(np.abs(gap) > 0.01):  # away from the threshold, the sampled answer is exact
            assert got[i] == np.any(gap < 0), i
            decided += 1
    assert decided > 150 and 0.1 < got.mean() < 0.9


def test_prop_keep_cuts_a_box_in_front_of_the_body_and_keeps_the_body_in_front_of_one():
    from tracker.fitting.scene import SceneOptions, SceneTracker
    from tracker.fitting.tracking import Tracker

    model = load_model("knossow40")
    cams = ring_cameras(3, size=(320, 240))
    p = model.zero()
    pelvis = forward(model, p).translation[0]
    towards = cams[0].center - pelvis
    towards[2] = 0.0
    towards /= np.linalg.norm(towards)
    front = PropBox.from_values(list(pelvis + 0.6 * towards - 0.15) + list(pelvis + 0.6 * towards + 0.15))
    back = PropBox.from_values(list(pelvis - 0.6 * towards - 0.3) + list(pelvis - 0.6 * towards + 0.3))
    opts = SceneOptions(prop_depth_tol_m=0.02)
    st = SceneTracker(Tracker(model, cams), {}, options=opts, props=[front, back])
    keep, grown, body = st.prop_keep(p)[cams[0].name], st.explained(p)[cams[0].name], st.explained(p, 0.0)[cams[0].name]
    seen_front = prop_masks(cams[:1], [front])[cams[0].name]
    seen_back = prop_masks(cams[:1], [back])[cams[0].name] & ~seen_front
    # the masks' outline pixels, whose centres' rays can pass beside the box, left out
    inner = {k: cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
             for k, m in (("front", seen_front), ("back", seen_back))}
    # the box between the camera and the body hides it: none of its pixels is body
    assert np.count_nonzero(inner["front"] & grown) > 50 and not np.any(inner["front"] & keep)
    # the body in front of the other box: its pixels there stay body
    assert np.count_nonzero(seen_back & body) > 50
    assert np.count_nonzero(seen_back & body & keep) >= 0.98 * np.count_nonzero(seen_back & body)
    # outside the props' projections the keep is the grown projection
    outside = ~(seen_front | seen_back)
    assert np.array_equal(keep[outside], grown[outside])
    # without the ray test the grown projection keeps the box in front too (the old cut)
    st0 = SceneTracker(Tracker(model, cams), {}, options=SceneOptions(prop_margin_m=0.04), props=[front, back])
    assert np.any(seen_front & st0.prop_keep(p)[cams[0].name])
