"""``contourcap review``: the fitted model drawn over a session's images (video, contact sheet)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from capture.session import load_session
from service.cli import main
from service.review import FrameOverlay, load_records, status_lines, write_review
from tracker.imaging.contours import extremal_contours
from tracker.body.kinematics import forward
from service.offline import session_model
from tracker.imaging.overlay import CENTRE, LEFT, RIGHT, side_of
from tracker.synthetic.synth import bundled_motion

from service.synthetic_session import make_synthetic_session
from tests.support.files import read_jsonl, read_video

N_FRAMES = 5
SIZE = (200, 150)


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("review")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=2, size=SIZE, frames=N_FRAMES,
                           n_background=3, seed=5)
    return out


def _truth(session_dir):
    return read_jsonl(session_dir / "ground_truth.jsonl")


def test_video_and_sheet_from_the_cli(session_dir, tmp_path, capsys):
    video, sheet = tmp_path / "review.mp4", tmp_path / "sheet.png"
    rc = main(["review", str(session_dir), str(session_dir / "ground_truth.jsonl"), "--out", str(video),
               "--sheet", str(sheet), "--sheet-frames", "3", "--names", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    frames = read_video(video)
    assert len(frames) == N_FRAMES
    h, w = frames[0].shape[:2]
    assert w == 2 * SIZE[0] and SIZE[1] < h < SIZE[1] + 80  # two cameras side by side under a status band
    assert all(f.shape == frames[0].shape for f in frames)
    img = cv2.imread(str(sheet))
    assert img is not None and 200 < img.shape[1] <= 1600
    assert f"reviewed {N_FRAMES} frames" in capsys.readouterr().out
    part = tmp_path / "part.avi"
    assert main(["review", str(session_dir), str(session_dir / "ground_truth.jsonl"), "--out", str(part),
                 "--frames", "1:3", "--quiet"]) == 0
    assert len(read_video(part)) == 2 and read_video(part)[0].shape == frames[0].shape


def test_frames_without_a_record_are_kept_and_marked(session_dir, tmp_path):
    recs = [r for r in _truth(session_dir) if r["frame"] != 2]
    summary = write_review(load_session(session_dir), recs, video=tmp_path / "gap.avi", sheet=tmp_path / "gap.png",
                           sheet_frames=2)
    assert (summary.frames, summary.with_record) == (N_FRAMES, N_FRAMES - 1)
    assert len(read_video(tmp_path / "gap.avi")) == N_FRAMES
    assert cv2.imread(str(tmp_path / "gap.png")) is not None


def _nearest_palette(pixels: np.ndarray) -> np.ndarray:
    """Index into (LEFT, RIGHT, CENTRE, black, white) of the nearest colour of each pixel (n, 3)."""
    palette = np.array([LEFT, RIGHT, CENTRE, (0, 0, 0), (255, 255, 255)], float)
    return np.argmin(np.linalg.norm(pixels[:, None, :].astype(float) - palette[None], axis=2), axis=1)


def test_contours_are_drawn_where_the_model_projects_in_their_side_colour(session_dir):
    session = load_session(session_dir)
    rec = _truth(session_dir)[2]
    overlay = FrameOverlay(session)
    black = {n: np.zeros((SIZE[1], SIZE[0], 3), np.uint8) for n in session.camera_names}
    drawn, boxes = overlay.draw(black, {k: v for k, v in rec.items() if k != "joints"})  # contours only
    model = session_model(session, rec["model"])
    cams = [session.camera_model(n) for n in session.camera_names]
    con = extremal_contours(model, forward(model, np.asarray(rec["params"])), cams, n_samples=overlay.n_samples)
    side = np.array([side_of(n) for n in model.part_names])[con.part]
    uv = np.round(con.uv).astype(int)
    for c, name in enumerate(session.camera_names):
        img = drawn[name]
        assert name in boxes
        for s, want in ((1, 0), (2, 1)):  # left parts -> LEFT, right parts -> RIGHT
            sel = (con.cam == c) & con.visible & (side == s)
            assert sel.sum() > 20
            got = _nearest_palette(img[uv[sel, 1], uv[sel, 0]])
            assert np.mean(got == want) > 0.7, (name, s, np.bincount(got, minlength=5))
        # nothing is painted far from the model's outline
        painted = img.any(axis=2)
        near = np.zeros_like(painted, np.uint8)
        vis = (con.cam == c) & con.visible
        near[uv[vis, 1], uv[vis, 0]] = 1
        near = cv2.dilate(near, np.ones((9, 9), np.uint8)).astype(bool)
        assert painted.sum() > 100 and not np.any(painted & ~near)


def test_a_not_ok_record_shows_its_reason(session_dir, tmp_path):
    session = load_session(session_dir)
    recs = _truth(session_dir)
    recs[3] = dict(recs[3], ok=False, reason="poor fit: silhouette IoU 0.42 < 0.8", rms_px=4.5, iou=0.42,
                   failed=["iou"])
    lines = status_lines(recs[3], 3)
    assert "NOT OK: poor fit: silhouette IoU 0.42 < 0.8" in lines[0] and "IoU 0.42" in lines[1]
    assert "rms 4.50 px" in lines[1]
    assert status_lines(recs[1], 1)[0] == "frame 1: ok"
    assert "no pose record" in status_lines(None, 7)[0]
    path = tmp_path / "poses.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in recs))
    video = tmp_path / "r.avi"
    summary = write_review(session, load_records(path), video=video)
    assert (summary.frames, summary.with_record, summary.ok) == (N_FRAMES, N_FRAMES, N_FRAMES - 1)
    frames = read_video(video)
    band = 30  # the status band above the cameras

    def reddish(img):
        b, g, r = (img[:band].astype(int)[..., i] for i in range(3))
        return int(np.sum((r > g + 60) & (r > 120))), int(np.sum((g > r + 60) & (g > 120)))

    red_bad, green_bad = reddish(frames[3])
    red_ok, green_ok = reddish(frames[1])
    assert red_bad > 30 and green_bad < red_bad / 4  # the not-ok frame's status is written in red
    assert green_ok > 30 and red_ok < green_ok / 4


@pytest.mark.parametrize("content, message", [
    ("not json\n", "not a JSON pose record"),
    ('{"frame": "x"}\n', "non-negative integer 'frame'"),
    ('{"frame": 0, "model": "knossow40", "params": [0.0, 1.0]}\n', "model 'knossow40' needs"),
    ('{"frame": 0, "model": "nomodel", "params": [0.0]}\n', "unknown model 'nomodel'"),
    ("", "no pose record"),
])
def test_bad_records_give_one_clear_error(session_dir, tmp_path, capsys, content, message):
    path = tmp_path / "bad.jsonl"
    path.write_text(content)
    rc = main(["review", str(session_dir), str(path), "--out", str(tmp_path / "r.mp4"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and message in err and err.startswith("contourcap review: error:")
    assert not (tmp_path / "r.mp4").exists()


def test_bad_paths_give_one_clear_error(session_dir, tmp_path, capsys):
    rc = main(["review", str(session_dir), str(tmp_path / "missing.jsonl"), "--out", str(tmp_path / "r.mp4")])
    assert rc == 2 and "missing.jsonl" in capsys.readouterr().err
    rc = main(["review", str(tmp_path / "nosession"), str(session_dir / "ground_truth.jsonl"),
               "--out", str(tmp_path / "r.mp4")])
    assert rc == 2 and "contourcap review: error:" in capsys.readouterr().err
    rc = main(["review", str(session_dir), str(session_dir / "ground_truth.jsonl")])
    assert rc == 2 and "--out" in capsys.readouterr().err
