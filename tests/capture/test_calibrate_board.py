"""Board detection, corners from a user outline, intrinsics and bundle-adjusted extrinsics on synthetic scenes with known answers."""

import functools

import cv2
import numpy as np
import pytest

from capture.board import (
    CharucoBoard,
    Checkerboard,
    _template,
    corners_from_outline,
    detect_checkerboard,
    relabel_to_origin,
)
from capture.calibrate import (
    BoardObservation,
    Intrinsics,
    calibrate_extrinsics,
    intrinsics_from_frames,
    rodrigues_batch,
)
from capture.camera import Camera, rodrigues_to_matrix

BOARD = Checkerboard(8, 6, 0.115)
UU_DIST = np.array([-0.37, 0.20, 3e-4, 2e-5, -0.07])


@functools.lru_cache(maxsize=8)
def _pixel_rays(K_flat: tuple, dist: tuple, size: tuple, s: int) -> np.ndarray:
    """Normalised rays (h*s*w*s, 2) of every pixel of a camera supersampled s times (cached: pose-independent)."""
    K = np.array(K_flat).reshape(3, 3)
    K[:2] *= s
    K[0, 2] += (s - 1) / 2.0
    K[1, 2] += (s - 1) / 2.0
    u, v = np.meshgrid(np.arange(size[0] * s, dtype=np.float64), np.arange(size[1] * s, dtype=np.float64))
    return cv2.undistortPoints(np.stack([u.ravel(), v.ravel()], -1).reshape(-1, 1, 2), K, np.array(dist)).reshape(-1, 2)


def _render(cam: Camera, texture: np.ndarray, metres_per_px: float, origin_px: tuple[float, float],
            board2world: np.ndarray = np.eye(4), supersample: int = 3) -> np.ndarray:
    """Grey image (h, w) of a planar texture seen by ``cam``; texture pixel (u, v) is board point
    ((u - origin_px[0]) * metres_per_px, (v - origin_px[1]) * metres_per_px, 0); white elsewhere."""
    s = supersample
    w, h = cam.width * s, cam.height * s
    xy = _pixel_rays(tuple(cam.matrix.ravel()), tuple(cam.distortion), cam.size, s)
    # ray in the board frame: X = C + lambda d, board plane z = 0
    cam2board = np.linalg.inv(cam.world2cam @ board2world)
    d = np.c_[xy, np.ones(len(xy))] @ cam2board[:3, :3].T
    C = cam2board[:3, 3]
    lam = -C[2] / d[:, 2]
    P = C + lam[:, None] * d
    mx = (P[:, 0] / metres_per_px + origin_px[0]).reshape(h, w).astype(np.float32)
    my = (P[:, 1] / metres_per_px + origin_px[1]).reshape(h, w).astype(np.float32)
    mx[(lam <= 0).reshape(h, w)] = -1e6
    img = cv2.remap(texture.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=200.0)
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA).clip(0, 255).astype(np.uint8)


def _checker_view(cam, board2world=np.eye(4), supersample=3):
    pps, border = 40.0, 0.6
    tex = _template(BOARD, pps, border)
    org = ((1 + border) * pps - 0.5, (1 + border) * pps - 0.5)  # template pixel centre convention
    return _render(cam, tex, BOARD.square_m / pps, org, board2world, supersample)


def _truth(cam, board2world=np.eye(4)):
    X = BOARD.object_points() @ board2world[:3, :3].T + board2world[:3, 3]
    return cam.project(X)


def test_rodrigues_batch_matches_single(rng):
    r = rng.normal(0, 1.5, (50, 3))
    r[0] = 0.0
    r[1] = [np.pi, 0, 0]
    Rs = rodrigues_batch(r)
    for rv, R in zip(r, Rs):
        np.testing.assert_allclose(R, rodrigues_to_matrix(rv), atol=1e-12)


def test_relabel_to_origin_puts_nearest_corner_first(rng):
    pts = rng.uniform(0, 500, (BOARD.n_corners, 2))
    grid = pts.reshape(BOARD.rows, BOARD.cols, 2)
    for target in (grid[0, 0], grid[0, -1], grid[-1, 0], grid[-1, -1]):
        out = relabel_to_origin(pts, BOARD, target + 1.0)
        np.testing.assert_array_equal(out[0], target)
        g = out.reshape(BOARD.rows, BOARD.cols, 2)
        # the same points, and every output row is an input row (maybe reversed): cols stay along rows
        assert {tuple(p) for p in out} == {tuple(p) for p in pts}
        for row in g:
            assert any(np.array_equal(row, r) or np.array_equal(row, r[::-1]) for r in grid)


def test_detection_and_outline_recover_true_corners():
    cam = Camera.look_at("c", [0.45 + 2.6, 0.3 - 1.0, 1.6], [0.45, 0.3, 0.0], size=(644, 486), fov_deg=66, distortion=UU_DIST)
    img = _checker_view(cam)
    truth = _truth(cam)
    found = detect_checkerboard(img, BOARD)
    assert found is not None
    found = relabel_to_origin(found, BOARD, truth[0])
    err_detect = np.linalg.norm(found - truth, axis=1)
    assert err_detect.max() < 0.45, err_detect.max()  # SB's accuracy on a distorted, oblique view
    # user outline: outer pattern corners, each clicked 2 px off
    s = BOARD.square_m
    outer = np.array([[-s, -s, 0], [8 * s, -s, 0], [8 * s, 6 * s, 0], [-s, 6 * s, 0]])
    clicks = cam.project(outer) + np.array([[2.0, -1.5], [-1.8, 2.0], [1.5, 1.7], [-2.0, -1.2]])
    oc = corners_from_outline(img, BOARD, clicks, matrix=cam.matrix, distortion=cam.distortion)
    err_outline = np.linalg.norm(oc.corners - truth, axis=1)
    assert oc.correlation > 0.8
    assert err_outline.max() < 0.1, err_outline.max()
    assert oc.moved_px > 1.0  # the 2 px click errors were corrected


def test_outline_on_grazing_small_board():
    # far and low: board ~ 150 px wide and squares ~ 5 px tall, as in uu_studio cam1/cam4
    cam = Camera.look_at("c", [0.45 + 4.2, 0.3 + 2.0, 1.3], [0.45, 0.3, 0.0], size=(644, 486), fov_deg=66, distortion=UU_DIST)
    img = _checker_view(cam)
    truth = _truth(cam)
    s = BOARD.square_m
    outer = np.array([[-s, -s, 0], [8 * s, -s, 0], [8 * s, 6 * s, 0], [-s, 6 * s, 0]])
    clicks = cam.project(outer) + np.array([[1.5, -1.0], [-1.5, 1.0], [1.0, 1.0], [-1.0, -1.0]])
    oc = corners_from_outline(img, BOARD, clicks, matrix=cam.matrix, distortion=cam.distortion)
    err = np.linalg.norm(oc.corners - truth, axis=1)
    assert err.max() < 0.15, err.max()


def test_outline_validation():
    with pytest.raises(ValueError, match="4 finite"):
        corners_from_outline(np.zeros((10, 10)), BOARD, [[0, 0], [1, 1]], matrix=np.eye(3), distortion=np.zeros(5))
    with pytest.raises(ValueError, match="long side first"):
        Checkerboard(6, 8, 0.1)


def _studio_cameras():
    return [
        Camera.look_at(f"cam{i}", [0.4 + 3.2 * np.cos(a), 0.3 + 3.2 * np.sin(a), 2.2 + 0.3 * i], [0.4, 0.3, 0.3],
                       size=(644, 486), fov_deg=70, distortion=UU_DIST * 0.5)
        for i, a in enumerate([0.3, 1.9, 3.4, 5.0])
    ]


def _pose(rvec, t):
    T = np.eye(4)
    T[:3, :3] = rodrigues_to_matrix(rvec)
    T[:3, 3] = t
    return T


def test_bundle_adjustment_recovers_cameras_and_placements(rng):
    cams = _studio_cameras()
    # placement 0 = floor board; placements 1..3 = the board held up in the room
    placements = {0: np.eye(4), 1: _pose([0.9, 0.1, 0.2], [0.0, 0.0, 0.8]),
                  2: _pose([1.2, -0.3, 0.8], [0.2, -0.2, 1.0]), 3: _pose([-1.0, 0.4, -0.5], [0.6, 0.9, 0.6])}
    obs = []
    for cam in cams:
        for p, T in placements.items():
            X = BOARD.object_points() @ T[:3, :3].T + T[:3, 3]
            if np.any(cam.depth(X) <= 0) or not np.all(cam.in_image(cam.project(X))):
                continue
            if p == 0 and cam.name in ("cam2", "cam3"):
                continue  # these two never see the floor board: linked through the other placements
            uv = cam.project(X) + rng.normal(0, 0.3, (len(X), 2))
            obs.append(BoardObservation(cam.name, p, uv, BOARD.object_points(), "detected", (p,)))
    assert {o.camera for o in obs if o.placement == 0} == {"cam0", "cam1"}
    intr = [Intrinsics.from_camera(c) for c in cams] + [Intrinsics("lonely", cams[0].matrix, np.zeros(5), (644, 486))]
    res = calibrate_extrinsics(intr, obs)
    assert res.failed == {"lonely": "no board observation"}
    assert len(res.cameras) == 4
    for truth, est in zip(cams, res.cameras):
        assert np.linalg.norm(truth.center - est.center) < 0.01
        assert np.degrees(np.arccos(np.clip((np.trace(truth.rotation.T @ est.rotation) - 1) / 2, -1, 1))) < 0.2
    for p, T in placements.items():
        assert np.abs(res.placements[p][:3, 3] - T[:3, 3]).max() < 0.01
    assert 0.35 < res.rms_px < 0.45  # per-point error norm: 0.3 px per axis noise -> 0.42 px
    for r in res.reports:
        if r.used:
            assert r.rms_px < 0.5 and r.n_points >= 48


def test_bundle_adjustment_names_unlinked_camera(rng):
    cams = _studio_cameras()[:2]
    T = _pose([0.9, 0.1, 0.2], [0.0, 0.0, 0.8])
    X0 = BOARD.object_points()
    obs = [BoardObservation("cam0", 0, cams[0].project(X0), X0),
           BoardObservation("cam1", 5, cams[1].project(X0 @ T[:3, :3].T + T[:3, 3]), X0)]
    res = calibrate_extrinsics([Intrinsics.from_camera(c) for c in cams], obs)
    assert [c.name for c in res.cameras] == ["cam0"]
    assert "not linked to the floor board" in res.failed["cam1"]


def _view_poses(rng, n):
    """n board2world poses facing a camera at (0, 0, 0.3) that looks along +y (board z away from it, as OpenCV expects)."""
    return [_pose(rng.normal(0, 0.3, 3) + [-np.pi / 2, 0, 0], [rng.uniform(-0.9, 0.1), rng.uniform(1.3, 2.0), rng.uniform(0.2, 0.9)])
            for _ in range(n)]


def _assert_intrinsics_close(K, dist, truth):
    assert abs(K[0, 0] / truth.matrix[0, 0] - 1) < 0.01
    assert abs(K[1, 1] / truth.matrix[1, 1] - 1) < 0.01
    assert np.abs(K[:2, 2] - truth.matrix[:2, 2]).max() < 3.0
    # the lens model reproduces the true distortion where the boards were seen (no extrapolation to the corners):
    # distortion field (raw pixel - ideal pinhole pixel) of each model, in pixels
    uv = np.stack(np.meshgrid(np.linspace(150, 500, 8), np.linspace(100, 400, 6)), -1).reshape(-1, 2)
    field_true = uv - cv2.undistortPoints(uv.reshape(-1, 1, 2), truth.matrix, truth.distortion, P=truth.matrix).reshape(-1, 2)
    field_est = uv - cv2.undistortPoints(uv.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
    assert np.abs(field_true).max() > 10  # the lens really distorts here
    assert np.abs(field_true - field_est).max() < 1.0


def test_intrinsics_from_rendered_checkerboard_views(rng):
    truth = Camera.look_at("c", [0, 0, 0.3], [0, 1, 0.3], size=(644, 486), fov_deg=70, distortion=[-0.25, 0.08, 0, 0, 0])
    frames = [_checker_view(truth, T, supersample=2) for T in _view_poses(rng, 7)]
    res = intrinsics_from_frames("c", frames, BOARD)
    assert res.n_views >= 5
    assert res.rms_px < 0.3
    _assert_intrinsics_close(res.intrinsics.matrix, res.intrinsics.distortion, truth)


def test_intrinsics_needs_three_views():
    blank = [np.full((100, 120), 255, np.uint8)] * 4
    with pytest.raises(ValueError, match=r"camera 'c': board found in 0 of 4 frames"):
        intrinsics_from_frames("c", blank, BOARD)
    with pytest.raises(ValueError, match=r"camera 'c': frame 2 is 60x50, frame 0 is 120x100"):
        intrinsics_from_frames("c", blank[:2] + [np.zeros((50, 60), np.uint8)], BOARD)
    with pytest.raises(ValueError, match=r"max_views: need at least 3"):
        intrinsics_from_frames("c", blank, BOARD, max_views=2)


def test_cli_intrinsics_from_charuco_image_sequence(rng, tmp_path, capsys):
    from capture.calibration import load_calibration
    from service.cli import main

    truth = Camera.look_at("c", [0, 0, 0.3], [0, 1, 0.3], size=(644, 486), fov_deg=70, distortion=[-0.25, 0.08, 0, 0, 0])
    board = CharucoBoard(7, 5, 0.16, 0.12)
    tex = board.cv_board().generateImage((7 * 60, 5 * 60), marginSize=0).astype(np.float32)
    tex = cv2.copyMakeBorder(tex, 30, 30, 30, 30, cv2.BORDER_CONSTANT, value=255)
    (tmp_path / "cam0").mkdir()
    for k, T in enumerate(_view_poses(rng, 6)):
        cv2.imwrite(str(tmp_path / "cam0" / f"{k:02d}.png"), _render(truth, tex, 0.16 / 60.0, (29.5, 29.5), T, supersample=2))
    out = tmp_path / "intrinsics.toml"
    rc = main(["calibrate", "intrinsics", "--charuco", "7x5", "--square", "0.16", "--marker", "0.12", "--every", "1",
               "--video", f"cam0={tmp_path / 'cam0' / '%02d.png'}", "--out", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr()
    (cam,) = load_calibration(out)
    assert cam.name == "cam0" and cam.size == (644, 486)
    _assert_intrinsics_close(cam.matrix, cam.distortion, truth)
    assert "cam0: ok views=6" in capsys.readouterr().out
    # a camera whose frames never show the board is named, with the reason, and exit status 1
    cv2.imwrite(str(tmp_path / "blank.png"), np.full((486, 644), 128, np.uint8))
    rc = main(["calibrate", "intrinsics", "--charuco", "7x5", "--square", "0.16", "--marker", "0.12",
               "--video", f"cam0={tmp_path / 'cam0'}", "--video", f"cam1={tmp_path / 'blank.png'}",
               "--every", "1", "--out", str(out), "--quiet"])
    assert rc == 1
    printed = capsys.readouterr().out
    assert "cam0: ok views=6" in printed  # the same images, given as a folder
    assert "cam1: NOT CALIBRATED: camera 'cam1': board found in 0 of 1 frames" in printed


def test_corner_file_errors_name_file_camera_key(tmp_path):
    from capture.floor_board import load_corner_file

    p = tmp_path / "c.toml"
    p.write_text("[cam1]\ncorners = [[1, 2], [3, 4], [5, 6]]\n")
    with pytest.raises(ValueError, match=r"c.toml \[cam1\] key 'corners': expected 4"):
        load_corner_file(p)
    p.write_text("[cam2]\norigin = [1, 2, 3]\n")
    with pytest.raises(ValueError, match=r"c.toml \[cam2\] key 'origin'"):
        load_corner_file(p)
    p.write_text("[cam2]\norigin = [nan, 2]\n")
    with pytest.raises(ValueError, match=r"c.toml \[cam2\] key 'origin': pixel coordinates must be finite"):
        load_corner_file(p)
    p.write_text("[cam3]\nfoo = 1\n")
    with pytest.raises(ValueError, match=r"c.toml \[cam3\]: needs key 'corners'"):
        load_corner_file(p)
    p.write_text('[cam1]\ncorners = [[1, 2], [3, 4], [5, 6], [7, 8]]\n[cam2]\norigin = [9.5, 10]\n')
    outlines, hints = load_corner_file(p)
    np.testing.assert_array_equal(outlines["cam1"][3], [7, 8])
    np.testing.assert_array_equal(hints["cam2"], [9.5, 10])


def test_read_board_frames_image_and_bad_files(tmp_path):
    from capture.floor_board import read_board_frames

    img = np.full((40, 60), 77, np.uint8)
    cv2.imwrite(str(tmp_path / "board.png"), img)
    frames, ids = read_board_frames(tmp_path / "board.png")
    assert ids == [0] and np.array_equal(frames[0], img)
    (tmp_path / "junk.avi").write_bytes(b"not a video at all")
    with pytest.raises(ValueError, match="junk.avi"):
        read_board_frames(tmp_path / "junk.avi")
    with pytest.raises(FileNotFoundError, match="missing.avi"):
        read_board_frames(tmp_path / "missing.avi")


@pytest.mark.parametrize("args, message", [
    (["--board", "8x", "--square", "0.1"], "--board '8x': expected COLSxROWS"),
    (["--board", "8x6x2", "--square", "0.1"], "--board '8x6x2': expected COLSxROWS"),
    (["--charuco", "7", "--square", "0.1", "--marker", "0.05"], "--charuco '7': expected COLSxROWS"),
    (["--board-file", "{not_xml}"], "not_xml.xml: not a readable OpenCV FileStorage file"),
    (["--board", "8x6", "--square", "0.1", "--every", "0"], "--every (>= 1) / --max-views (>= 3): got 0 / 40"),
    (["--board", "8x6", "--square", "0.1", "--max-views", "2"], "--every (>= 1) / --max-views (>= 3): got 5 / 2"),
    (["--board", "8x6", "--square", "0.1", "--report", "{tmp}"], "is a folder; give a file name"),
    (["--board", "8x6", "--square", "0.1", "--report", "{tmp}/no/r.json"], "/no does not exist"),
])  # fmt: skip
def test_cli_intrinsics_bad_arguments_named(tmp_path, capsys, args, message):
    from service.cli import main

    cv2.imwrite(str(tmp_path / "blank.png"), np.full((48, 64), 128, np.uint8))
    (tmp_path / "not_xml.xml").write_text("[this is]\nnot = 'xml'\n")
    args = [a.format(not_xml=tmp_path / "not_xml.xml", tmp=tmp_path) for a in args]
    rc = main(["calibrate", "intrinsics", *args, "--video", f"cam0={tmp_path / 'blank.png'}",
               "--out", str(tmp_path / "i.toml"), "--quiet"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("contourcap calibrate: error: ") and message in err and "Traceback" not in err
    assert not (tmp_path / "i.toml").exists()


def test_cli_names_the_unreadable_image_of_a_folder(tmp_path, capsys):
    from service.cli import main

    (tmp_path / "cam0").mkdir()
    cv2.imwrite(str(tmp_path / "cam0" / "00.png"), np.full((48, 64), 128, np.uint8))
    (tmp_path / "cam0" / "01.png").write_bytes(b"not a png")
    rc = main(["calibrate", "intrinsics", "--board", "8x6", "--square", "0.1", "--every", "1",
               "--video", f"cam0={tmp_path / 'cam0'}", "--out", str(tmp_path / "i.toml"), "--quiet"])
    assert rc == 1
    assert "cam0: NOT CALIBRATED:" in (out := capsys.readouterr().out) and "unreadable image(s) ['01.png']" in out


@pytest.mark.parametrize("w, h, size, match", [
    ("8", "6", '"abc"', r"key 'CheckerBoardSquareSize' must be a positive number"),  # real() of text was 1.8e305
    ("8", "6", "-115", r"key 'CheckerBoardSquareSize' must be a positive number"),
    ("8.5", "6", "115", r"must be whole numbers"),
    ("1", "6", "115", r"board.xml: board needs at least 2"),
])  # fmt: skip
def test_board_xml_values_checked(tmp_path, w, h, size, match):
    p = tmp_path / "board.xml"
    p.write_text(f'<?xml version="1.0"?>\n<opencv_storage>\n<CheckerBoardWidth>{w}</CheckerBoardWidth>\n'
                 f"<CheckerBoardHeight>{h}</CheckerBoardHeight>\n<CheckerBoardSquareSize>{size}</CheckerBoardSquareSize>\n"
                 "</opencv_storage>\n")
    with pytest.raises(ValueError, match=match):
        Checkerboard.from_opencv_xml(p)
