"""The floor test on the coloured hull's samples (tracker/blobs/floor_samples.py) and the blob
tracker's first pose, on rendered people the body model was not made from (tracker/synthetic/people.py)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from segmentation import BackgroundModel
from tracker.blobs import HullOptions, coloured_hull
from tracker.blobs.floor_samples import SampleFloorTest
from tracker.blobs.tracking import hull_support
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.motions import make_motion
from tracker.synthetic.people import Studio, body_primitives, make_subject, subject_motion
from tracker.synthetic.scene import fit_ring_cameras
from tracker.synthetic.synth import bundled_motion


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock")
        yield


def _frame(seed: int, *, dark_floor: bool, n_cams: int = 4):
    """Cameras, background models, one decoded frame set and the true joints (16, 3) of a walking subject."""
    skeleton = load_bvh(bundled_motion("scaled_131_01"))
    subject = make_subject(seed, dark_shoes=seed % 2 == 0)
    motion = make_motion("walk_turn", skeleton, frames=2, rng=np.random.default_rng(3000 + seed))
    sm = subject_motion(motion, subject)
    prim = body_primitives(sm, subject)
    pts = np.concatenate([prim.spheres(f)[0].reshape(-1, 3) for f in range(prim.n_frames)])
    cams = fit_ring_cameras(pts, n_cams, size=(320, 240))
    studio = Studio(cams, seed=seed, dark_floor=dark_floor)
    rng = np.random.default_rng(seed)
    models = {c.name: BackgroundModel.from_frames([studio.camera_output(bg, rng)[0] for _ in range(10)])
              for c, bg in zip(cams, studio.backgrounds)}
    images, _ = studio.render(prim, 0)
    decoded = {c.name: studio.camera_output(img, rng)[0] for c, img in zip(cams, images)}
    return cams, models, decoded, sm.joints[0]


def _leg_points(joints: np.ndarray) -> np.ndarray:
    """Points along both thighs and shanks (hip-knee-ankle, JOINT_NAMES order), (m, 3)."""
    from tracker.synthetic.people import JOINT_NAMES

    j = {n: joints[i] for i, n in enumerate(JOINT_NAMES)}
    t = np.linspace(0.1, 0.9, 9)[:, None]
    segs = [(j[f"{s}_hip"], j[f"{s}_knee"]) for s in ("left", "right")]
    segs += [(j[f"{s}_knee"], j[f"{s}_ankle"]) for s in ("left", "right")]
    return np.concatenate([a + t * (b - a) for a, b in segs])


def _hull(cams, models, images, joints, floor):
    zone = np.stack([joints.min(0) - 0.4, joints.max(0) + 0.4])
    zone[0, 2] = 0.0
    test = SampleFloorTest(cams, models) if floor else None
    return coloured_hull(cams, [images[c.name] for c in cams], [models[c.name] for c in cams], zone,
                         options=HullOptions(), floor=None if test is None else test.for_frame(images))


def test_dark_trousers_on_a_dark_floor_stay_in_the_hull():
    # subject 3: black trousers on a dark floor, taken for shadow by the per-sample test
    cams, models, images, joints = _frame(3, dark_floor=True)
    legs = _leg_points(joints)
    before = hull_support(_hull(cams, models, images, joints, False), legs, tolerance_m=0.015).mean()
    after = hull_support(_hull(cams, models, images, joints, True), legs, tolerance_m=0.015).mean()
    assert before < 0.5
    assert after > 0.9


def test_a_cast_shadow_does_not_enter_the_hull():
    # subject 1 on a light floor: the floor test must not turn the shadow into floor voxels
    cams, models, images, joints = _frame(1, dark_floor=False)
    legs = _leg_points(joints)
    plain = _hull(cams, models, images, joints, False)
    tested = _hull(cams, models, images, joints, True)
    assert hull_support(tested, legs, tolerance_m=0.015).mean() > 0.9
    low = lambda h: h.volumes[h.centres[:, 2] < 0.06].sum()  # noqa: E731  (the feet and anything on the floor)
    assert low(tested) <= 1.2 * low(plain) + 1e-4
    assert tested.volumes.sum() <= 1.1 * plain.volumes.sum()


def test_contour_start_hands_over_a_settled_pose():
    # subject 3 starting in a T-pose (dark floor, black trousers): the blobs are learnt at the pose
    # the contour tracker hands over; it must not be turned round and must be near the truth
    # (measured: handed over on the 6th frame set, 88 mm from the truth, IK floor ~48 mm for this
    # subject; on the benchmark's tpose_start clip of subject 3 a single silhouette search gave a pose
    # turned round, 350 mm)
    from tracker.body.kinematics import forward, joint_centre_array
    from tracker.body.model import load_model
    from tracker.blobs.start import ContourStart, StartPending
    from tracker.synthetic.evaluation import frame_errors, mirrored_frames
    from tracker.synthetic.people import JOINT_NAMES, subject_height

    skeleton = load_bvh(bundled_motion("scaled_131_01"))
    subject = make_subject(3, dark_shoes=False)
    motion = make_motion("tpose_start", skeleton, frames=8, rng=np.random.default_rng(3003))
    sm = subject_motion(motion, subject)
    prim = body_primitives(sm, subject)
    pts = np.concatenate([prim.spheres(f)[0].reshape(-1, 3) for f in range(prim.n_frames)])
    cams = fit_ring_cameras(pts, 4, size=(320, 240))
    studio = Studio(cams, seed=3, dark_floor=True)
    rng = np.random.default_rng(3)
    models = {c.name: BackgroundModel.from_frames([studio.camera_output(bg, rng)[0] for _ in range(10)])
              for c, bg in zip(cams, studio.backgrounds)}
    model = load_model("knossow40", height_m=subject_height(motion, subject))
    start = ContourStart(model, cams, models, max_frames=6)
    for f in range(6):
        images, _ = studio.render(prim, f)
        decoded = {c.name: studio.camera_output(img, rng)[0] for c, img in zip(cams, images)}
        try:
            params = start(cams, decoded)
        except StartPending as exc:
            assert "params" in exc.record or "reason" in exc.record
            continue
        break
    else:
        raise AssertionError("ContourStart never handed over within max_frames")
    joints = joint_centre_array(model, forward(model, params))
    pred = np.array([joints[model.joint_names.index(j)] for j in JOINT_NAMES])[None]
    err = frame_errors(pred, sm.joints[f][None])
    assert not mirrored_frames(err).any()
    assert err["mpjpe"][0] < 0.13


def test_damped_least_squares_with_the_root_lowers_the_trunk_into_a_crouch():
    # goals of a crouch (hips and knees flexed, the trunk lower) from a standing start: with the
    # root free every goal pulls the trunk down; with the joints only it stays at its height
    from tracker.blobs import blob_layout, damped_least_squares
    from tracker.body.kinematics import forward
    from tracker.body.model import ROOT_TRANSLATION, load_model

    model = load_model("knossow40", height_m=1.7)
    lay = blob_layout(model)
    target = model.zero()
    for side in ("left", "right"):
        target[model.param_index(f"{side}_thigh.flexion")] = np.radians(80.0)
        target[model.param_index(f"{side}_shank.flexion")] = np.radians(110.0)
    target[np.flatnonzero(model.param_kind == ROOT_TRANSLATION)[2]] -= 0.35
    goals = forward(model, target).to_world(lay.part, lay.point)
    err = {}
    for root in (False, True):
        out = damped_least_squares(model, model.zero(), lay.part, lay.point, goals, iterations=30, root=root)
        assert model.within_limits(out)
        err[root] = np.linalg.norm(forward(model, out).to_world(lay.part, lay.point) - goals, axis=1).mean()
    assert err[True] < 0.01
    assert err[False] > 0.1


def _numpy_floor_votes(cameras, models, name, images, points, ratio, low):
    # the floor test's votes written with Camera.project and BackgroundModel.distance_at, as the
    # reference for the compiled loop (segmentation.floor.floor_votes' Notes)
    body, shadow, seen = (np.zeros(len(points), int) for _ in range(3))
    for other, cam in cameras.items():
        if other == name or other not in images:
            continue
        w, h = cam.size
        Xc = cam.to_camera(points)
        with np.errstate(divide="ignore", invalid="ignore"):
            uv0 = (Xc[:, :2] / Xc[:, 2:]) @ cam.matrix[:2, :2].T + cam.matrix[:2, 2]
        uv = np.rint(cam.project(points))
        ok = (Xc[:, 2] > 1e-6) & (uv0[:, 0] > -0.25 * w) & (uv0[:, 0] < 1.25 * w) & (uv0[:, 1] > -0.25 * h)
        ok &= (uv0[:, 1] < 1.25 * h) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        idx = np.flatnonzero(ok)
        seen[idx] = 1
        unchanged, darkened = models[other].distance_at(images[other], uv[idx, 1].astype(np.intp),
                                                        uv[idx, 0].astype(np.intp), ratio[idx])
        body[idx] += (unchanged <= low) & (unchanged < darkened)
        shadow[idx] += (darkened <= low) & (darkened <= unchanged)
    return (body > shadow) | (seen == 0)


def test_floor_votes_match_a_numpy_form_with_lens_distortion():
    # segmentation.floor.floor_votes (one compiled loop per voting camera, shared by the image floor test
    # and the hull's SampleFloorTest) against its numpy form, on floor points behind shadow-like samples
    from dataclasses import replace

    from segmentation.floor import floor_votes

    cams, models, images, _ = _frame(1, dark_floor=True)
    cams = [replace(c, distortion=np.array([-0.1, 0.02, 0.001, -0.002, 0.0])) if i % 2 else c
            for i, c in enumerate(cams)]
    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(-3, 3, 4000), rng.uniform(-3, 3, 4000), np.zeros(4000)])
    ratio = rng.uniform(0.4, 1.0, 4000).astype(np.float32)
    test = SampleFloorTest(cams, models)
    by_name = {c.name: c for c in cams}
    for name in by_name:
        want = _numpy_floor_votes(by_name, models, name, images, pts, ratio, test.low)
        got = floor_votes(by_name, models, name, images, pts, ratio, test.low)
        assert 0 < want.sum() < len(want)  # both verdicts occur
        assert np.mean(got != want) < 1e-3  # float32 rounding may flip a tie
