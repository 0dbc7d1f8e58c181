"""A seated person (not the cone model) on a rendered chair that is absent from the background.

``tracker.synthetic.seated`` sits a ``tracker.synthetic.people`` subject on a chair (seat, four
legs, backrest) drawn into the frames only, as in a real take whose empty-room plate has no
chair.  The chair is in every silhouette.  Tracked by ``tracker.fitting.scene`` with the chair's
operator boxes (``--prop``, ``tracker.fitting.props``) the legs' error against the ground truth
is compared with the same track without them.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from capture.calibration import save_calibration
from capture.session import load_session, write_session_toml
from segmentation.background import BackgroundModel
from service.offline import track_session
from tracker.fitting.props import PropBox
from tracker.fitting.scene import SceneOptions
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.motions import motion_to_bvh
from tracker.synthetic.people import JOINT_NAMES, Studio, body_primitives, make_subject, subject_height, subject_motion
from tracker.synthetic.scene import fit_ring_cameras
from tracker.synthetic.seated import chair_boxes, chair_props, seated_track
from tracker.synthetic.synth import bundled_motion

JUDGED = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
          "left_knee", "right_knee", "left_ankle", "right_ankle")


def render_seated_session(root: Path, *, seed: int, frames: int, cameras: int = 4, size=(320, 240)):
    """Render the seated scene into a session at ``root``; returns (truth (n, 16, 3), background
    models, the chair's operator boxes)."""
    rng = np.random.default_rng(seed)
    bvh = motion_to_bvh(seated_track(frames, fps=25.0, rng=rng), load_bvh(bundled_motion("scaled_131_01")))
    subject = make_subject(seed)
    sm = subject_motion(bvh, subject)
    prim = body_primitives(sm, subject)
    boxes = chair_boxes(sm, subject.radius["thigh"])
    pts = np.concatenate([prim.spheres(f)[0].reshape(-1, 3) for f in range(prim.n_frames)])
    cams = fit_ring_cameras(pts, cameras, size=tuple(size))
    studio = Studio(cams, seed=seed)
    backgrounds = {c.name: BackgroundModel.from_frames([studio.camera_output(bg, rng)[0] for _ in range(8)], window_px=1)
                   for c, bg in zip(cams, studio.backgrounds)}  # fmt: skip
    for c in cams:
        (root / c.name).mkdir(parents=True, exist_ok=True)
    for f in range(frames):
        images, _ = studio.render(prim, f, boxes=boxes)
        for c, img in zip(cams, images):
            (root / c.name / f"{f:06d}.jpg").write_bytes(studio.camera_output(img, rng)[1])
    save_calibration(root / "calibration.toml", cams)
    write_session_toml(root, name="seated", fps=25.0, cameras=[{"name": c.name, "images": f"{c.name}/%06d.jpg"}
                                                               for c in cams], height_m=subject_height(bvh, subject))
    return sm.joints, backgrounds, chair_props(boxes)


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
    session = load_session(root)
    return list(track_session(session, backgrounds=backgrounds, scene=SceneOptions(**scene),
                              props=[PropBox.from_values(p) for p in props] if props else None))


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


@pytest.fixture(scope="module")
def seated_scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("seated")
    truth, backgrounds, props = render_seated_session(root, seed=SEED, frames=FRAMES)
    return root, truth, backgrounds, props


@pytest.mark.slow
def test_chair_props_keep_the_legs_off_the_chair(seated_scene):
    root, truth, backgrounds, props = seated_scene
    # the operator's boxes hold the chair: the seat's top under the hips, the legs in front of it
    seat = PropBox.from_values(props[0])
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
