"""Occlusion of contour points: a scene with a known answer, and random poses against a ray march."""

import warnings

import numpy as np
import pytest

from capture.camera import Camera
from tracker.imaging.contours import extremal_contours
from tracker.body.kinematics import forward
from tracker.body.model import JOINT_NAMES, load_model
from tracker.imaging.visibility import hidden_points

BODY_R, BAR_R, BAR_X = 0.15, 0.03, 0.5


def bar_model(tmp_path):
    """A 1 m tall upright cylinder (radius 0.15 m, centre 1 m above the floor) and a thin horizontal bar
    (radius 0.03 m, 1 m long along world y) 0.5 m in front of it (+x).  height_m = 1: fractions are metres."""
    joints = "\n".join(f'{name} = {{ part = "body", point = [0.0, 0.0, 0.0] }}' for name in JOINT_NAMES)
    text = f"""
[model]
name = "bar"

[[part]]
name = "body"
joint = "free"
offset = [0.0, 0.0, 1.0]
cone = {{ a = {BODY_R}, b = {BODY_R}, k = 0.0, z1 = -0.5, z2 = 0.5 }}

[[part]]
name = "bar"
parent = "body"
offset = [{BAR_X}, 0.0, 0.0]
rotation = [-90, 0, 0]
cone = {{ a = {BAR_R}, b = {BAR_R}, k = 0.0, z1 = -0.5, z2 = 0.5 }}

[joints]
{joints}
"""
    path = tmp_path / "bar.toml"
    path.write_text(text)
    return load_model(path, height_m=1.0)


def line_distance_2d(origin, target, centre):
    """Distance from ``centre`` to the 2-D line through ``origin`` and ``target`` (points (n, 2))."""
    d = target - origin
    w = centre - origin
    return np.abs(d[:, 0] * w[:, 1] - d[:, 1] * w[:, 0]) / np.linalg.norm(d, axis=1)


def test_known_occluder_hides_exactly_the_expected_points(tmp_path):
    model = bar_model(tmp_path)
    front = Camera.look_at("front", [5.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    back = Camera.look_at("back", [-5.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    pose = forward(model, model.zero())
    ct = extremal_contours(model, pose, [front, back], n_samples=41)
    assert ct.valid.all()
    hidden = ct.valid & ~ct.visible
    body, bar = model.part_index("body"), model.part_index("bar")
    P = ct.points
    # front: the bar (axis along y at x = 0.5, z = 1) hides the body's rulings where the line of sight,
    # seen in the x-z plane, passes within BAR_R of the bar's axis
    sel = (ct.cam == 0) & (ct.part == body)
    dist = line_distance_2d(np.array([[5.0, 1.0]]), P[sel][:, [0, 2]], np.array([[BAR_X, 1.0]]))
    assert np.abs(dist - BAR_R).min() > 1e-4  # no sample sits on the edge of the shadow
    np.testing.assert_array_equal(hidden[sel], dist < BAR_R)
    assert (dist < BAR_R).sum() == 6  # 3 heights on each side
    assert not hidden[(ct.cam == 0) & (ct.part == bar)].any()  # nothing is in front of the bar
    # back: the body hides the middle of the bar's rulings (x-y plane, within BODY_R of the body's axis)
    sel = (ct.cam == 1) & (ct.part == bar)
    dist = line_distance_2d(np.array([[-5.0, 0.0]]), P[sel][:, [0, 1]], np.array([[0.0, 0.0]]))
    assert np.abs(dist - BODY_R).min() > 1e-4
    np.testing.assert_array_equal(hidden[sel], dist < BODY_R)
    assert (dist < BODY_R).sum() >= 10
    assert not hidden[(ct.cam == 1) & (ct.part == body)].any()


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_arm_in_front_of_the_torso_seen_from_the_side(name):
    """T-pose seen from the front-left at shoulder height: the left arm and thigh are in front of
    everything and never hidden; the right arm and thigh, behind the torso, are partly hidden."""
    model = load_model(name, height_m=1.75)
    pose = forward(model, model.zero())
    cam = Camera.look_at("left", [1.0, 3.0, 1.4], [0.0, 0.0, 1.2])
    ct = extremal_contours(model, pose, [cam], n_samples=10)
    assert ct.valid.all()
    hidden = ~ct.visible
    for part in ("left_upper_arm", "left_forearm", "left_hand", "left_thigh"):
        assert not hidden[ct.part == model.part_index(part)].any(), part
    for part in ("right_upper_arm", "right_hand", "right_thigh"):
        assert 3 <= hidden[ct.part == model.part_index(part)].sum() <= 17, part


def solid_value(model, pose, q, X):
    """max(cone test, cap tests) of world points X (..., 3) against part q: <= 0 exactly inside the solid."""
    a, b, k, z1, z2 = model.cones[q]
    x = (X - pose.translation[q]) @ pose.rotation[q]  # into the part frame
    cone = (x[..., 0] / a) ** 2 + (x[..., 1] / b) ** 2 - (1 + k * x[..., 2]) ** 2
    return np.maximum(cone, np.maximum(z1 - x[..., 2], x[..., 2] - z2) / (z2 - z1))


def ray_march(model, pose, centres, ct, rows, n_steps=200):
    """min over s in [0, 1] and over the other parts of ``solid_value`` along each line of sight, shape (n,).

    A dense march, then a ternary-search refinement around the best step (the value is continuous in s,
    so thin crossings of an end cap are found too).  Negative: the segment enters another part."""
    s = np.linspace(0.0, 1.0, n_steps + 1)
    C = centres[ct.cam[rows]]
    D = ct.points[rows] - C
    worst = np.full(rows.size, np.inf)
    for q in range(model.n_parts):
        val = solid_value(model, pose, q, C[:, None, :] + s[None, :, None] * D[:, None, :])  # (n, steps)
        coarse = val.min(axis=1)
        near = np.flatnonzero(coarse < 1.0)  # far from the solid everywhere: no refinement needed
        best = s[val[near].argmin(axis=1)]
        lo, hi = np.clip(best - 1.0 / n_steps, 0, 1), np.clip(best + 1.0 / n_steps, 0, 1)
        Cn, Dn = C[near], D[near]
        for _ in range(45):
            m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
            f1 = solid_value(model, pose, q, Cn + m1[:, None] * Dn)
            left = f1 < solid_value(model, pose, q, Cn + m2[:, None] * Dn)
            lo, hi = np.where(left, lo, m1), np.where(left, m2, hi)
        coarse[near] = np.minimum(coarse[near], solid_value(model, pose, q, Cn + lo[:, None] * Dn))
        worst = np.where(ct.part[rows] == q, worst, np.minimum(worst, coarse))
    return worst


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_random_poses_agree_with_a_ray_march(name, rng):
    model = load_model(name, height_m=1.75)
    angles = np.linspace(0, 2 * np.pi, 4, endpoint=False)
    cams = [Camera.look_at(f"c{i}", [3 * np.cos(q), 3 * np.sin(q), 1.6], [0, 0, 1.0]) for i, q in enumerate(angles)]
    centres = np.array([c.center for c in cams])
    n_hidden = 0
    for _ in range(3):
        pose = forward(model, model.random_params(rng))
        ct = extremal_contours(model, pose, cams, n_samples=3)
        rows = np.flatnonzero(ct.valid)
        worst = ray_march(model, pose, centres, ct, rows)
        hidden = ~ct.visible[rows]
        # every flagged point really has an occluder on its line of sight, and every point the march
        # finds inside another part is flagged
        assert (worst[hidden] < 1e-9).all()
        assert hidden[worst < -1e-9].all()
        n_hidden += hidden.sum()
    assert n_hidden > 20


def test_culling_does_not_change_the_answer(rng):
    """The image-plane cull only skips pairs that cannot intersect: all pairs against the culled result."""
    model = load_model("knossow54", height_m=1.75)
    cams = [Camera.look_at("c0", [2.0, 1.0, 1.5], [0, 0, 1.0]), Camera.look_at("c1", [0.5, -2.5, 0.3], [0, 0, 1.2])]
    pose = forward(model, model.random_params(rng))
    ct = extremal_contours(model, pose, cams, n_samples=6, visibility=False)
    got = hidden_points(model, pose, cams, ct.cam, ct.part, ct.points)
    worst = ray_march(model, pose, np.array([c.center for c in cams]), ct, np.arange(ct.n_points))
    assert got.sum() > 20
    assert (worst[got] < 1e-9).all() and got[worst < -1e-9].all()
    only = ct.valid & (rng.random(ct.n_points) < 0.5)
    np.testing.assert_array_equal(hidden_points(model, pose, cams, ct.cam, ct.part, ct.points, only=only), got & only)


def test_camera_inside_a_part_hides_without_warnings():
    model = load_model("knossow40", height_m=1.75)
    pose = forward(model, model.zero())
    torso = model.part_index("torso")
    inside = pose.to_world(np.array([torso]), np.array([[0.0, 0.0, 0.05]]))[0]
    cam = Camera.look_at("inside", inside, inside + [0.3, 0.0, -1.0], fov_deg=120)  # sees the legs
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ct = extremal_contours(model, pose, [cam], n_samples=4)
        assert not ct.valid[ct.part == torso].any()
        # seen from inside the torso, every other part is behind the torso's wall
        assert ct.valid.any() and not ct.visible.any()
