"""`contourcap calibrate extrinsics` on the real uu_studio recording (4 cameras, floor checkerboard).

cam2 and cam3 find the board automatically; cam1 and cam4 use the committed
user outline (capture/uu_studio_corners.toml).  Independent check: each
calibrated camera's centre must project onto where that camera is visibly
standing in another camera's image (camera heads read off the frames by eye).
"""

import json
from pathlib import Path

import numpy as np
import pytest

from capture.calibration import load_calibration
from service.cli import main

CORNERS = Path(__file__).resolve().parents[2] / "capture" / "uu_studio_corners.toml"
# where camera B's head is seen in camera A's checkerboard.avi frame 0 (pixels, by eye on 6x zooms)
SEEN = {("cam1", "cam3"): (198.0, 160.0), ("cam3", "cam1"): (471.0, 203.0)}


def _args(d: Path, cams, out: Path, *extra):
    args = ["calibrate", "extrinsics", "--intrinsics", str(d), "--board-file", str(d / "checkerboard.xml"),
            "--out", str(out), "--quiet"]
    for c in cams:
        args += ["--video", f"{c}={d / c / 'checkerboard.avi'}"]
    return args + list(extra)


def test_uu_studio_extrinsics_all_four_cameras(shared_data, tmp_path, capsys):
    d = shared_data / "uu_studio"
    out, rep = tmp_path / "calibration.toml", tmp_path / "report.json"
    rc = main(_args(d, ["cam1", "cam2", "cam3", "cam4"], out, "--corners-file", str(CORNERS), "--report", str(rep)))
    assert rc == 0, capsys.readouterr()
    report = json.loads(rep.read_text())
    assert {n: r["method"] for n, r in report.items() if n != "_overall"} == {
        "cam1": "manual", "cam2": "detected", "cam3": "detected", "cam4": "manual"}
    for name in ("cam1", "cam2", "cam3", "cam4"):
        assert report[name]["rms_px"] < 1.0
        assert report[name]["points"] == 48
    assert report["_overall"]["rms_px"] < 1.0
    cams = {c.name: c for c in load_calibration(out)}
    assert sorted(cams) == ["cam1", "cam2", "cam3", "cam4"]
    board_centre = np.array([0.4025, 0.2875, 0.0])  # 8 x 6 corners, 115 mm: the board spans 7 x 5 squares of corners
    for c in cams.values():
        # on tripods around the room, above the floor, all looking at the board
        assert 1.0 < c.center[2] < 4.0, (c.name, c.center)
        assert 2.0 < np.linalg.norm(c.center - board_centre) < 6.0
        assert c.depth(board_centre) > 0 and c.in_image(c.project(board_centre))
    for (a, b), seen in SEEN.items():
        uv = cams[a].project(cams[b].center)
        assert cams[a].depth(cams[b].center) > 0
        assert np.linalg.norm(uv - seen) < 8.0, (a, b, uv)
    # the cameras stand at distinct places around the board (not a degenerate or mirrored solution)
    centres = np.array([c.center[:2] for c in cams.values()]) - board_centre[:2]
    angles = np.sort(np.degrees(np.arctan2(centres[:, 1], centres[:, 0])))
    assert np.diff(np.r_[angles, angles[0] + 360]).min() > 30


def test_camera_without_board_or_corners_is_named(shared_data, tmp_path, capsys):
    d = shared_data / "uu_studio"
    out = tmp_path / "partial.toml"
    rc = main(_args(d, ["cam1", "cam2"], out, "--frames", "2"))
    captured = capsys.readouterr()
    assert rc == 1
    assert "cam1: NOT CALIBRATED: board not found" in captured.out
    assert "--corners" in captured.out
    assert [c.name for c in load_calibration(out)] == ["cam2"]


def test_bad_corner_argument_is_named(shared_data, tmp_path, capsys):
    d = shared_data / "uu_studio"
    rc = main(_args(d, ["cam1"], tmp_path / "x.toml", "--corners", "cam1=1,2;3,4"))
    assert rc == 2
    assert "--corners" in capsys.readouterr().err
    rc = main(_args(d, ["cam9"], tmp_path / "x.toml"))
    assert rc == 2


def test_manual_outline_is_robust_to_click_errors(shared_data):
    """Outlines clicked up to 4 px off give the same inner corners (ECC multi-start picks the same optimum)."""
    from capture.board import Checkerboard, corners_from_outline
    from capture.calib_formats import read_opencv_camera
    from capture.floor_board import load_corner_file, read_board_frames

    d = shared_data / "uu_studio"
    board = Checkerboard.from_opencv_xml(d / "checkerboard.xml")
    outlines, _ = load_corner_file(CORNERS)
    cam = read_opencv_camera(d / "cam4" / "config.xml", size=(644, 486))
    frames, _ = read_board_frames(d / "cam4" / "checkerboard.avi", n_frames=3)
    mean = np.mean(np.stack([f.astype(np.float32) for f in frames]), axis=0)
    ref = corners_from_outline(mean, board, outlines["cam4"], matrix=cam.matrix, distortion=cam.distortion)
    rng = np.random.default_rng(5)
    for _ in range(2):
        clicks = outlines["cam4"] + rng.uniform(-4, 4, (4, 2))
        got = corners_from_outline(mean, board, clicks, matrix=cam.matrix, distortion=cam.distortion)
        assert np.abs(got.corners - ref.corners).max() < 0.05
        assert got.correlation == pytest.approx(ref.correlation, abs=1e-3)
