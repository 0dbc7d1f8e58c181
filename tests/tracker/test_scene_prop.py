"""A prop in the silhouette: a box beside the subject, in every frame but not in the background.

The synthetic hop session is rendered, then a static box standing on the floor beside the
subject is painted into every frame (behind the body: only where the frame shows background),
never into the background video.  Every camera's silhouette therefore holds the box.  Tracked
with ``tracker.fitting.scene`` the box is learned as clutter and cut: the gate passes and the
fit stays on the body; before it is learned the box lowers the silhouette IoU below the gate.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from capture.session import load_session
from service.offline import track_session
from tracker.fitting.scene import SceneOptions
from tracker.fitting.tracking import TrackerOptions
from tracker.synthetic.synth import bundled_motion

from service.synthetic_session import make_synthetic_session
from tests.support.files import read_jsonl

FRAMES = 60


def _truth(root):
    return read_jsonl(root / "ground_truth.jsonl")


def _mean_error_mm(record: dict, truth: list[dict]) -> float:
    joints = truth[record["frame"]]["joints"]
    return 1e3 * float(np.mean([np.linalg.norm(np.subtract(record["joints"][k], joints[k])) for k in joints]))


def _box_corners(centre_xy, size=(0.3, 0.3, 0.45)) -> np.ndarray:
    sx, sy, sz = size
    x, y = centre_xy
    return np.array([[x + dx * sx / 2, y + dy * sy / 2, z] for dx in (-1, 1) for dy in (-1, 1) for z in (0.0, sz)])


def _paint_box(root: Path, corners: np.ndarray) -> int:
    """Paint the box (flat grey faces, darker sides) into every frame image behind the body;
    returns the number of frames painted."""
    session = load_session(root)
    painted = 0
    for name in session.camera_names:
        cam = session.camera_model(name)
        bg_path = session.camera(name).background
        cap = cv2.VideoCapture(str(bg_path))
        ok, background = cap.read()
        cap.release()
        assert ok, f"cannot read {bg_path}"
        uv = cam.project(corners)
        poly = np.zeros((cam.height, cam.width), np.uint8)
        cv2.fillConvexPoly(poly, cv2.convexHull(np.round(uv * 16).astype(np.int32)), 255, shift=4)
        pattern = session.camera(name).images
        for path in sorted(Path(pattern).parent.glob("*.png")):
            img = cv2.imread(str(path))
            behind = (poly > 0) & (cv2.absdiff(img, background).max(axis=2) < 40)
            img[behind] = (90, 110, 150)
            cv2.imwrite(str(path), img)
            painted += 1
    return painted


@pytest.fixture(scope="module")
def prop_session(tmp_path_factory) -> Path:
    root = make_synthetic_session(bundled_motion("scaled_131_03"), tmp_path_factory.mktemp("prop") / "hop",
                                  cameras=6, size=(320, 240), frames=FRAMES, n_background=10, seed=7, codec="png")
    truth = _truth(root)
    pelvis = np.mean([t["joints"]["pelvis"] for t in truth], axis=0)
    assert _paint_box(root, _box_corners(pelvis[:2] + [0.0, 0.6])) == 6 * FRAMES
    return root


@pytest.mark.slow
def test_prop_beside_subject_is_learned_and_cut(prop_session):
    truth = _truth(prop_session)
    session = load_session(prop_session)
    first = list(track_session(session, scene=SceneOptions(), retrack=False))
    # before anything is learned the box is in every silhouette and the gate sees it
    # (measured: IoU 0.59-0.60; tracked without the scene handling 0 of 60 frames ok, IoU 0.56-0.62)
    assert not first[0]["ok"] and "IoU" in first[0]["reason"], first[0].get("reason")
    # the gate's own checks, without the unexplained-boundary check (which the next test adds)
    scene = list(track_session(session, scene=SceneOptions(), options=TrackerOptions(uncovered_margin=None)))
    # offline, the warm-up is fitted again from the settled state, the box learned (measured: 25 of
    # 25 ok at 20-29 mm; their first fits 0 ok at 16-35 mm): ok, and honestly so
    early = scene[:FRAMES // 2]
    assert np.mean([r["ok"] for r in early]) >= 0.9, [r.get("reason") for r in early]
    assert all(_mean_error_mm(r, truth) < 40.0 for r in early if r["ok"])
    late = slice(FRAMES // 2, None)  # after the learning (SceneOptions.learn_frames + warm-up)
    ok_scene = np.mean([r["ok"] for r in scene[late]])
    err_scene = [_mean_error_mm(r, truth) for r in scene[late]]
    # measured: 30 of 30 ok, 23 mm (without the scene handling 39 mm)
    assert ok_scene >= 0.9, [r.get("reason") for r in scene[late]]
    assert np.mean(err_scene) < 32.0, [round(e) for e in err_scene]


def _worst_joint_mm(record: dict, truth: list[dict], names) -> float:
    joints = truth[record["frame"]]["joints"]
    return 1e3 * max(float(np.linalg.norm(np.subtract(record["joints"][k], joints[k]))) for k in names)


@pytest.mark.slow
def test_uncovered_check_changes_flags_not_poses_and_refuses_the_lost_leg(prop_session):
    truth = _truth(prop_session)
    session = load_session(prop_session)
    off = list(track_session(session, scene=SceneOptions(), options=TrackerOptions(uncovered_margin=None)))
    on = list(track_session(session, scene=SceneOptions()))  # the default: the check on
    assert TrackerOptions().uncovered_margin is not None
    # the warm-up's choice between a refit and its first fit does not follow the check's verdict
    # (service.offline.refit_kept): every pose is the same, only the check's refusals are added
    assert [r["frame"] for r in on] == [r["frame"] for r in off]
    for a, b in zip(off, on):
        np.testing.assert_array_equal(a["params"], b["params"])
        assert b["ok"] == (a["ok"] and "uncovered" not in b.get("failed", ())), (a.get("reason"), b.get("reason"))
    # measured: a left ankle drifts off in the camera beside the box (frames 43-56, 26-139 mm off) while
    # the mean figures pass; the check refuses it (without it the frames 49-55, 103-139 mm off, are ok)
    legs = ("left_knee", "right_knee", "left_ankle", "right_ankle")
    lost = [r for r in on if _worst_joint_mm(r, truth, legs) > 100.0]
    assert lost, "the clip's lost leg: no leg joint more than 100 mm off"
    assert not any(r["ok"] for r in lost), [r["frame"] for r in lost if r["ok"]]
