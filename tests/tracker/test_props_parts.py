"""Chair parts: hollow props (a chair's outline, ``[[prop]] hollow = true``) and solid parts in the
ray test; the thighs' tapered clearance from the props."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.fitting.props import PropBox, PropPenalty, prop_masks, prop_rays
from tracker.synthetic.scene import ring_cameras


def _chair_between(model, p, cam, *, gap_m: float = 0.3):
    """An outline box between ``cam`` and the body at ``p`` (0.6 m from the pelvis towards the
    camera, 0.5 m wide across the view, from the floor to 1 m) and two thin solid legs at its
    sides, ``gap_m`` apart: (outline, [legs])."""
    pelvis = forward(model, p).translation[0]
    towards = cam.center - pelvis
    towards[2] = 0.0
    towards /= np.linalg.norm(towards)
    across = np.array([-towards[1], towards[0], 0.0])
    c = pelvis + 0.6 * towards
    c[2] = 0.0
    corners = [c + s * 0.25 * across + t * 0.1 * towards for s in (-1, 1) for t in (-1, 1)]
    lo, hi = np.min(corners, axis=0), np.max(corners, axis=0) + [0, 0, 1.0]
    outline = PropBox.from_values(list(lo) + list(hi), solid=False)
    legs = []
    for s in (-1, 1):
        m = c + s * (0.5 * gap_m + 0.02) * across
        legs.append(PropBox.from_values(list(m - [0.02, 0.02, 0.0]) + list(m + [0.02, 0.02, 1.0])))
    return outline, legs


def test_prop_rays_enter_solid_boxes_only():
    cams = ring_cameras(3, size=(80, 60))
    hollow = PropBox.from_values([-0.2, -0.2, 0.0, 0.2, 0.2, 0.45], solid=False)
    slab = PropBox.from_values([-0.2, -0.2, 0.40, 0.2, 0.2, 0.45])
    only_hollow = prop_rays(cams, [hollow], prop_masks(cams, [hollow]))
    both = prop_rays(cams, [hollow, slab], prop_masks(cams, [hollow, slab]))
    solid = prop_rays(cams, [PropBox(hollow.lo, hollow.hi)], prop_masks(cams, [hollow]))
    alone = prop_rays(cams, [slab], prop_masks(cams, [hollow]))
    for cam in cams:
        assert len(only_hollow[cam.name].pixels) > 50 and not np.any(np.isfinite(only_hollow[cam.name].entry))
        # the hollow box is still met (the ray test runs along those rays); a solid entry is a meeting
        assert np.array_equal(only_hollow[cam.name].through, np.isfinite(solid[cam.name].entry))
        assert np.all(both[cam.name].through[np.isfinite(both[cam.name].entry)])
        # the same pixels (the outline's projection), entering the slab where the slab alone is entered
        assert np.array_equal(both[cam.name].pixels, alone[cam.name].pixels)
        assert np.array_equal(both[cam.name].entry, alone[cam.name].entry)
        # some rays pass the outline under the slab and enter nothing solid; as a solid box it is entered
        assert np.any(~np.isfinite(both[cam.name].entry)) and np.any(np.isfinite(both[cam.name].entry))
        assert np.all(solid[cam.name].entry[np.isfinite(both[cam.name].entry)] <= both[cam.name].entry[
            np.isfinite(both[cam.name].entry)] + 1e-9)


def test_penalty_keeps_the_body_out_of_a_hollow_box_too():
    model = load_model("knossow40")
    p = model.zero()
    pose = forward(model, p)
    pelvis = pose.translation[0]
    for solid in (True, False):
        box = PropBox.from_values(list(pelvis - 0.05) + list(pelvis + 0.05), solid=solid)
        assert PropPenalty([box], root_clearance=1.0).residuals(model, p)[0].sum() > 0


@pytest.mark.parametrize("gap_m", [0.2, 0.3])
def test_body_seen_between_the_legs_of_a_hollow_chair_is_kept(gap_m):
    from tracker.fitting.scene import SceneOptions, SceneTracker
    from tracker.fitting.tracking import Tracker

    model = load_model("knossow40")
    cams = ring_cameras(3, size=(320, 240))
    cam = cams[0]
    p = model.zero()
    outline, legs = _chair_between(model, p, cam, gap_m=gap_m)
    st = SceneTracker(Tracker(model, cams), {}, options=SceneOptions(prop_depth_tol_m=0.02), props=[outline, *legs])
    keep, body = st.prop_keep(p)[cam.name], st.explained(p, 0.0)[cam.name]
    grown = st.explained(p)[cam.name]
    erode = np.ones((5, 5), np.uint8)
    seen_legs = cv2.dilate(prop_masks([cam], legs)[cam.name].astype(np.uint8), erode).astype(bool)
    seen_outline = prop_masks([cam], [outline])[cam.name]
    core = cv2.erode(body.astype(np.uint8), erode).astype(bool)
    gap = seen_outline & ~seen_legs & core
    # the body seen through the gap between the legs stays body; the legs in front of it do not
    assert np.count_nonzero(gap) > 100
    assert np.count_nonzero(keep & gap) >= 0.98 * np.count_nonzero(gap)
    in_legs = cv2.erode(prop_masks([cam], legs)[cam.name].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.count_nonzero(in_legs & grown) > 20 and not np.any(in_legs & core & keep)
    # the outline's pixels away from the body (the floor seen through it) are cut, within the
    # projection's margin too where the ray passes the body
    assert not np.any(keep & seen_outline & ~grown)
    assert np.count_nonzero(grown & ~body & seen_outline & ~seen_legs & ~keep) > 20
    # the same outline taken as solid hides the body behind it (the old reading of a bounding box)
    st_solid = SceneTracker(Tracker(model, cams), {}, options=SceneOptions(prop_depth_tol_m=0.02),
                            props=[PropBox(outline.lo, outline.hi), *legs])
    inner = gap & cv2.erode(seen_outline.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert np.count_nonzero(inner) > 100 and not np.any(st_solid.prop_keep(p)[cam.name] & inner)


def test_session_hollow_flag(tmp_path, rng):
    from capture.session import SessionError, load_session
    from service.offline import session_props
    from tests.support.sessions import make_session

    make_session(tmp_path, rng, n_frames=2)
    path = tmp_path / "session.toml"
    text = path.read_text()
    path.write_text(text + "\n[[prop]]\nbox = [-0.3, 0.1, 0.0, 0.2, 0.6, 0.46]\nhollow = true\n"
                    "\n[[prop]]\nbox = [-0.3, 0.1, 0.4, 0.2, 0.6, 0.46]\n")
    session = load_session(tmp_path)
    assert session.hollow_props == (True, False)
    assert [b.solid for b in session_props(session)] == [False, True]
    path.write_text(text + "\n[[prop]]\nbox = [-0.3, 0.1, 0.0, 0.2, 0.6, 0.46]\nhollow = 1\n")
    with pytest.raises(SessionError, match="hollow"):
        load_session(tmp_path)


def test_thigh_taper_goes_from_the_root_clearance_at_the_hip_to_the_clearance_at_the_knee():
    model = load_model("knossow40")
    box = PropBox.from_values([5.0, 5.0, 0.0, 5.5, 5.5, 0.5])
    plain = PropPenalty([box], samples=5, clearance=1.2, root_clearance=0.3)
    taper = PropPenalty([box], samples=5, clearance=1.2, root_clearance=0.3, thigh_taper=True)
    part, _, need = plain._model_points(model)
    _, _, need_t = taper._model_points(model)
    thighs = np.isin(part, [i for i, n in enumerate(model.part_names) if n.endswith("thigh")])
    assert np.array_equal(need[~thighs], need_t[~thighs])
    ratio = (need_t[thighs] / need[thighs]).reshape(-1, 5)  # per thigh, hip end first
    assert np.allclose(ratio, np.linspace(0.3, 1.2, 5)[None, :] / 1.2)
    # a box just under a thigh's hip end: the tapered limit lets it sit lower
    p = model.zero()
    hip = forward(model, p).translation[model.part_names.index("left_thigh")]
    under = PropBox.from_values(list(hip + [-0.05, -0.05, -0.3]) + list(hip + [0.05, 0.05, -0.06]))
    r_plain = PropPenalty([under], clearance=1.2, root_clearance=0.3).residuals(model, p)[0].sum()
    r_taper = PropPenalty([under], clearance=1.2, root_clearance=0.3, thigh_taper=True).residuals(model, p)[0].sum()
    assert 0 <= r_taper < r_plain
