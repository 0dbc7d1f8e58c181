"""A seated person (not the cone model) on a rendered chair that is absent from the background.

``tracker.synthetic.seated`` sits a ``tracker.synthetic.people`` subject on a chair (seat, four
legs, backrest) drawn into the frames only, as in a real take whose empty-room plate has no
chair.  The chair is in every silhouette.  Tracked by ``tracker.fitting.scene`` with the chair's
operator boxes (``--prop``, ``tracker.fitting.props``) the legs' error against the ground truth
is compared with the same track without them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from capture.session import load_session
from service.backgrounds import background_models
from service.offline import session_props, track_session
from tracker.fitting.props import PropBox
from tracker.fitting.scene import SceneOptions
from tracker.synthetic.people import JOINT_NAMES
from tracker.synthetic.seated import write_seated_session

JUDGED = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
          "left_knee", "right_knee", "left_ankle", "right_ankle")


def render_seated_session(root: Path, *, seed: int, frames: int, size=(320, 240), props: str = "bounding"):
    """Render the seated scene into a session at ``root`` (``write_seated_session``, a ring of four
    cameras, its ``props``); returns (truth (n, 16, 3), background models, the session's props as
    ``PropBox``)."""
    truth, _, _ = write_seated_session(root, seed=seed, frames=frames, size=size, props=props)
    session = load_session(root)
    backgrounds, _ = background_models(session, list(session.camera_names))
    return truth, backgrounds, session_props(session)


def judged_errors_mm(records: list[dict], truth: np.ndarray) -> dict[str, float]:
    """Mean error (mm) per judged joint over the records."""
    idx = {n: i for i, n in enumerate(JOINT_NAMES)}
    out = {}
    for j in JUDGED:
        out[j] = 1e3 * float(np.mean([np.linalg.norm(np.subtract(r["joints"][j], truth[r["frame"], idx[j]]))
                                      for r in records if "joints" in r]))
    return out


def frame_errors_mm(records: list[dict], truth: np.ndarray) -> np.ndarray:
    """Per record, the mean error (mm) of the judged joints (NaN without joints)."""
    idx = [JOINT_NAMES.index(j) for j in JUDGED]
    return np.array([1e3 * float(np.mean(np.linalg.norm(np.array([r["joints"][j] for j in JUDGED])
                                                          - truth[r["frame"], idx], axis=1)))
                     if "joints" in r else np.nan for r in records])


def track(root: Path, backgrounds, props, **scene) -> list[dict]:
    """The scene tracker's records of the session at ``root`` with ``props`` (PropBox list or None)
    and ``SceneOptions(**scene)``."""
    session = load_session(root)
    return list(track_session(session, backgrounds=backgrounds, scene=SceneOptions(**scene), props=props or None))


if __name__ == "__main__":  # a measurement run: python -m tests.tracker.test_scene_seated SEED FRAMES
    import json
    import sys
    import tempfile

    seed, frames = int(sys.argv[1]), int(sys.argv[2])
    with tempfile.TemporaryDirectory() as tmp:
        truth, bgs, props = render_seated_session(Path(tmp), seed=seed, frames=frames)
        for name, p, auto in (("without", None, False), ("learned seat", None, True), ("with props", props, False)):
            recs = track(Path(tmp), bgs, p, auto_seat=auto)
            e = judged_errors_mm(recs, truth)
            fe, ok = frame_errors_mm(recs, truth), np.array([bool(r.get("ok")) for r in recs])
            print(json.dumps({"seed": seed, "run": name, "judged_mm": round(float(np.mean(list(e.values()))), 1),
                              "ok_percent": round(100 * float(np.mean(ok)), 1),
                              "false_ok_percent": round(100 * float(np.mean(ok & (fe > 80))), 1),
                              "ok_error_max_mm": round(float(np.max(fe[ok])), 1) if ok.any() else None,
                              "joints": {k: round(v, 1) for k, v in e.items()}}))


SEED, FRAMES = 2, 24
LEGS = ("left_knee", "right_knee", "left_ankle", "right_ankle")


def operator_boxes(parts: list) -> list:
    """The operator's boxes of a session written with ``props="parts"`` (the seat's outline, the slab,
    four legs, the backrest): the outline taken as solid and the backrest, as ``props="bounding"``."""
    outline = next(p for p in parts if not p.solid)
    return [PropBox(outline.lo, outline.hi), parts[-1]]


@pytest.fixture(scope="module")
def seated_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("seated")
    truth, backgrounds, parts = render_seated_session(root, seed=SEED, frames=FRAMES, props="parts")
    return root, truth, backgrounds, parts


@pytest.mark.slow
def test_chair_props_keep_the_legs_off_the_chair(seated_scene):
    root, truth, backgrounds, parts = seated_scene
    props = operator_boxes(parts)
    # the operator's boxes hold the chair: the seat's top under the hips, the legs in front of it
    seat = props[0]
    hips = truth[:, [JOINT_NAMES.index("left_hip"), JOINT_NAMES.index("right_hip")]].reshape(-1, 3)
    assert np.all(hips[:, 2] > seat.hi[2]) and np.all(seat.signed_distance(hips)[0] > 0)
    plain = track(root, backgrounds, None, auto_seat=False)
    boxed = track(root, backgrounds, props)
    legs_plain = np.mean([v for k, v in judged_errors_mm(plain, truth).items() if k in LEGS])
    legs_boxed = np.mean([v for k, v in judged_errors_mm(boxed, truth).items() if k in LEGS])
    # measured (docs/real_floor.md, seeds 1-3): legs 58 / 81 / 114 mm without, 44 / 35 / 93 mm with
    assert legs_boxed < legs_plain
    assert legs_boxed < 100.0
    # the gate stays honest: no frame reported ok with a judged error over 80 mm
    err = frame_errors_mm(boxed, truth)
    ok = np.array([bool(r.get("ok")) for r in boxed])
    assert not np.any(ok & (err > 80.0))


def test_studio_cameras_see_every_point_from_their_azimuths():
    from tracker.synthetic.seated import STUDIO_FRONT_SIDE, studio_cameras

    rng = np.random.default_rng(5)
    pts = rng.uniform([-0.4, -0.3, 0.0], [0.5, 0.3, 1.3], size=(200, 3))
    cams = studio_cameras(pts, size=(160, 120))
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    for cam, (az, dist) in zip(cams, STUDIO_FRONT_SIDE):
        uv = cam.project(pts)
        assert np.all((uv > 0) & (uv < [160, 120]))
        off = cam.center[:2] - centre[:2]
        assert abs(np.degrees(np.arctan2(off[1], off[0])) - az) < 1e-6 and abs(np.linalg.norm(off) - dist) < 1e-6


def test_written_seated_session_loads_with_the_chair_props(tmp_path):
    from tracker.synthetic.seated import STUDIO_FRONT_SIDE

    truth, subject, props = write_seated_session(tmp_path, seed=1, frames=2, layout=STUDIO_FRONT_SIDE,
                                                 size=(160, 120), n_background=2)
    session = load_session(tmp_path)
    assert len(session.camera_names) == 4 and truth.shape == (2, len(JOINT_NAMES), 3)
    assert np.allclose(session.props, props, atol=1e-4)
    hips = truth[:, [JOINT_NAMES.index("left_hip"), JOINT_NAMES.index("right_hip")]].reshape(-1, 3)
    assert np.all(hips[:, 2] > PropBox.from_values(props[0]).hi[2])


def test_seat_sink_raises_the_seat_top_into_the_thighs():
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.motions import motion_to_bvh
    from tracker.synthetic.people import make_subject, subject_motion
    from tracker.synthetic.seated import chair_boxes, seated_track
    from tracker.synthetic.synth import bundled_motion

    bvh = motion_to_bvh(seated_track(3, rng=np.random.default_rng(0)), load_bvh(bundled_motion("scaled_131_01")))
    subject = make_subject(2)
    sm = subject_motion(bvh, subject)
    r = subject.radius["thigh"]
    flat, sunk = chair_boxes(sm, r), chair_boxes(sm, r, sink_m=0.02)
    hip_z = sm.joints[:, [JOINT_NAMES.index("left_hip"), JOINT_NAMES.index("right_hip")], 2].min()
    assert np.isclose(flat[0][1][2], hip_z - r) and np.isclose(sunk[0][1][2], hip_z - r + 0.02)
    # every box but the seat's top moves with it: legs up to the slab, the backrest from the seat
    assert all(np.isclose(b[1][2] - a[1][2], 0.02) for a, b in zip(flat[:5], sunk[:5]))


@pytest.mark.slow
def test_chair_parts_with_the_ray_test_keep_the_legs_off_the_chair(seated_scene):
    # the seat's outline hollow, its slab, legs and backrest solid: the ray test sees the legs through
    # the chair from the cameras behind it (taking the outline as solid lost them: docs/real_floor.md)
    root, truth, backgrounds, parts = seated_scene
    assert [p.solid for p in parts] == [False] + [True] * 6
    plain = track(root, backgrounds, None, auto_seat=False)
    rayed = track(root, backgrounds, parts, prop_depth_tol_m=0.02)
    solid = track(root, backgrounds, operator_boxes(parts), prop_depth_tol_m=0.02)

    def legs(records):
        return np.mean([v for k, v in judged_errors_mm(records, truth).items() if k in LEGS])

    # measured (docs/real_floor.md round 15, seed 2): 63.6 mm without props, 35.7 with the parts,
    # 94.3 with the operator's boxes taken as solid
    assert legs(rayed) < legs(plain) and legs(rayed) < legs(solid) and legs(rayed) < 100.0
    err = frame_errors_mm(rayed, truth)
    ok = np.array([bool(r.get("ok")) for r in rayed])
    assert not np.any(ok & (err > 80.0))
