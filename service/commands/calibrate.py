"""``contourcap calibrate``: camera intrinsics from board videos, extrinsics from a board on the floor.

    contourcap calibrate intrinsics --board 9x6 --square 0.025 --video cam0=cam0_board.mp4 --out intrinsics.toml
    contourcap calibrate intrinsics --charuco 7x5 --square 0.04 --marker 0.03 --video cam0=... --out intrinsics.toml
    contourcap calibrate extrinsics --intrinsics intrinsics.toml --board-file checkerboard.xml \\
        --video cam1=cam1/checkerboard.avi ... --corners "cam1=356.8,298;445.5,321;390,348.5;300,317.7" \\
        --out calibration.toml

Extrinsics: the board lies on the floor, static; each camera's video is
sampled (``--frames``).  Where no detector finds the board, give its four
outer pattern corners (``--corners``, or a ``--corners-file``; see
``capture.floor_board``), origin first, then along the long side.  The
report names every camera: used (detected/manual, frames, RMS px) or why not.
Exit status 0 when every camera was calibrated, 1 when some were not (the
file then holds the others), 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from service.atomic import write_text_atomic
from service.progress import Progress

HELP = "calibrate cameras: intrinsics from board videos, extrinsics from a board lying on the floor"


def add_args(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="calib_step", metavar="STEP", required=True)
    for name, help_ in (("intrinsics", "K and distortion per camera from board views (checkerboard or ChArUco)"),
                        ("extrinsics", "camera poses from a board lying on the floor (world Z up, board corner = origin)")):
        p = sub.add_parser(name, help=help_, description=help_)
        p.add_argument("--video", action="append", default=[], metavar="CAM=PATH", required=True,
                       help="board video, image, image folder or sequence (cam0/%%04d.png) of a camera (repeat per camera)")
        p.add_argument("--board", metavar="COLSxROWS", help="checkerboard inner corners, e.g. 8x6")
        p.add_argument("--square", type=float, metavar="M", help="square size in metres")
        p.add_argument("--board-file", type=Path, metavar="XML",
                       help="OpenCV XML with CheckerBoardWidth/Height/SquareSize (mm), instead of --board/--square")
        p.add_argument("--out", type=Path, required=True, help="calibration TOML to write")
        p.add_argument("--report", type=Path, help="also write the report as JSON here")
        p.add_argument("--quiet", action="store_true", help="no progress bar")
        if name == "intrinsics":
            p.add_argument("--charuco", metavar="SXxSY", help="ChArUco squares, e.g. 7x5 (instead of --board)")
            p.add_argument("--marker", type=float, metavar="M", help="ChArUco marker size in metres")
            p.add_argument("--dictionary", default="DICT_4X4_50", help="ArUco dictionary (default DICT_4X4_50)")
            p.add_argument("--max-views", type=int, default=40, help="most board views per camera (default 40)")
            p.add_argument("--every", type=int, default=5, help="use every N-th video frame (default 5)")
        else:
            p.add_argument("--intrinsics", type=Path, required=True,
                           help="file or folder with the cameras' intrinsics (any format read_any_calibration reads)")
            p.add_argument("--corners", action="append", default=[], metavar="CAM=X,Y;X,Y;X,Y;X,Y",
                           help="the board's four outer corners in a camera: origin, long side, opposite, short side")
            p.add_argument("--corners-file", type=Path, help="TOML with [cam] corners = [[x, y] * 4] and/or origin = [x, y]")
            p.add_argument("--origin", action="append", default=[], metavar="CAM=X,Y",
                           help="pixel near the board corner that is the world origin, in a camera")
            p.add_argument("--frames", type=int, default=3, help="frames sampled per video (default 3; the board is static)")
    from service.commands.calibrate_subject import add_subject_args

    add_subject_args(sub.add_parser("subject", help="the subject's segment lengths from the first frames of a session",
                                    description="the subject's segment lengths from the first frames of a session"))


def _pairs(items, option: str) -> dict[str, str]:
    out = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"{option} {item!r}: expected CAM=VALUE")
        cam, value = item.split("=", 1)
        out[cam.strip()] = value.strip()
    return out


def _points(text: str, option: str, n: int) -> np.ndarray:
    try:
        pts = np.array([[float(v) for v in p.split(",")] for p in text.split(";") if p.strip()])
    except ValueError:
        raise ValueError(f"{option}{text!r}: expected numbers as X,Y;X,Y...") from None
    if pts.shape != (n, 2) or not np.all(np.isfinite(pts)):
        raise ValueError(f"{option}{text!r}: expected {n} X,Y pairs of finite numbers separated by ';'")
    return pts


def _grid(text: str, option: str) -> tuple[int, int]:
    """``"8x6"`` -> ``(8, 6)``; ``ValueError`` naming ``option`` otherwise."""
    parts = text.lower().split("x")
    try:
        if len(parts) != 2:
            raise ValueError
        return int(parts[0]), int(parts[1])
    except ValueError:
        raise ValueError(f"{option} {text!r}: expected COLSxROWS, two whole numbers such as 8x6") from None


def _board(args):
    from capture.board import CharucoBoard, Checkerboard

    if getattr(args, "charuco", None):
        sx, sy = _grid(args.charuco, "--charuco")
        if args.square is None or args.marker is None:
            raise ValueError("--charuco needs --square and --marker (metres)")
        return CharucoBoard(sx, sy, args.square, args.marker, args.dictionary)
    if args.board_file:
        return Checkerboard.from_opencv_xml(args.board_file)
    if not args.board or args.square is None:
        raise ValueError("give --board COLSxROWS and --square METRES (or --board-file)")
    c, r = _grid(args.board, "--board")
    return Checkerboard(max(c, r), min(c, r), args.square)


def _video_size(path: Path) -> tuple[int, int]:
    cap = cv2.VideoCapture(str(path))
    ok, frame = cap.read()
    cap.release()
    if not ok:
        img = cv2.imread(str(path))
        if img is None:
            raise ValueError(f"{path}: unreadable video/image")
        frame = img
    return int(frame.shape[1]), int(frame.shape[0])


_IMAGES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")


def _read_frames(path: Path, every: int) -> list[np.ndarray]:
    """Grey frames of a video, an image, a printf image pattern or a folder of images (every ``every``-th)."""
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in _IMAGES)[::every]
        if not files:
            raise ValueError(f"{path}: no images ({', '.join(_IMAGES)}) in this folder")
        frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in files]
        bad = [p.name for p, f in zip(files, frames) if f is None]
        if bad:
            raise ValueError(f"{path}: unreadable image(s) {bad[:5]}")
        return frames
    cap = cv2.VideoCapture(str(path))
    frames, k = [], 0
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        if k % every == 0:
            frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY))
        k += 1
    cap.release()
    if not frames:
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{path}: unreadable video/image")
        frames = [img]
    return frames


def _run_intrinsics(args, videos, bar) -> tuple[list, dict]:
    from capture.calibrate import intrinsics_from_frames
    from capture.camera import Camera

    board = _board(args)
    cams, report = [], {}
    for name, path in videos.items():
        try:
            res = intrinsics_from_frames(name, _read_frames(path, max(1, args.every)), board,
                                         max_views=args.max_views, progress=bar)
        except ValueError as exc:
            report[name] = {"used": False, "reason": str(exc)}
            continue
        i = res.intrinsics
        cams.append(Camera(name, i.matrix, i.distortion, np.eye(3), np.zeros(3), i.size))
        report[name] = {"used": True, "views": res.n_views, "rms_px": res.rms_px}
    return cams, report


def _run_extrinsics(args, videos, bar) -> tuple[list, dict]:
    from capture.calib_formats import read_any_calibration
    from capture.calibrate import Intrinsics
    from capture.floor_board import calibrate_floor, load_corner_file

    board = _board(args)
    sizes = {n: _video_size(p) for n, p in videos.items()}
    known = {c.name: c for c in read_any_calibration(args.intrinsics, size=next(iter(sizes.values())))}
    missing = [n for n in videos if n not in known]
    if missing:
        raise ValueError(f"{args.intrinsics}: no intrinsics for camera(s) {missing}; it holds {sorted(known)}")
    intr, size_notes = [], {}
    for n in videos:
        i = Intrinsics.from_camera(known[n])
        if i.size != sizes[n]:  # formats without an image size guess it; the video is the truth
            size_notes[n] = f"image size {i.size} in {args.intrinsics} replaced by the video's {sizes[n]}"
            i = Intrinsics(n, i.matrix, i.distortion, sizes[n])
        intr.append(i)
    outlines, hints = load_corner_file(args.corners_file) if args.corners_file else ({}, {})
    for cam, text in _pairs(args.corners, "--corners").items():
        outlines[cam] = _points(text, f"--corners {cam}=", 4)
    for cam, text in _pairs(args.origin, "--origin").items():
        hints[cam] = _points(text, f"--origin {cam}=", 1)[0]
    result = calibrate_floor(intr, videos, board, outlines=outlines, origin_hints=hints,
                             n_frames=args.frames, progress=bar)
    ext = result.extrinsics
    notes = {v.camera: "; ".join(x for x in (v.note, size_notes.get(v.camera, "")) if x) for v in result.views}
    report = {}
    for r in ext.reports:
        if r.used:
            cam = next(c for c in ext.cameras if c.name == r.name)
            report[r.name] = {"used": True, "method": r.method, "frames": list(r.frames), "points": r.n_points,
                              "rms_px": r.rms_px, "note": notes.get(r.name, ""), "height_m": float(cam.center[2])}
        else:
            report[r.name] = {"used": False, "reason": r.reason}
    report["_overall"] = {"rms_px": ext.rms_px, "board_axes_swapped": result.swap_axes, "solver": ext.message}
    return list(ext.cameras), report


def _check_output(path: Path | None, option: str) -> None:
    """Refuse an output path that could not be written, before the (slow) calibration runs."""
    if path is None:
        return
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give a file name")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: folder {path.parent} does not exist")


def run(args) -> int:
    from capture.calibration import save_calibration

    if args.calib_step == "subject":
        from service.commands.calibrate_subject import run_subject

        return run_subject(args)

    bar = Progress(unit="steps", enabled=not args.quiet)
    try:
        _check_output(args.out, "--out")
        _check_output(args.report, "--report")
        videos = {cam: Path(p) for cam, p in _pairs(args.video, "--video").items()}
        for cam, p in videos.items():
            if not p.exists() and "%" not in p.name:  # a printf pattern names an image sequence
                raise ValueError(f"--video {cam}={p}: file not found")
        if args.calib_step == "intrinsics" and (args.every < 1 or args.max_views < 3):
            raise ValueError(f"--every (>= 1) / --max-views (>= 3): got {args.every} / {args.max_views}")
        if args.calib_step == "extrinsics" and args.frames < 1:
            raise ValueError(f"--frames: expected >= 1, got {args.frames}")
        step = _run_intrinsics if args.calib_step == "intrinsics" else _run_extrinsics
        cams, report = step(args, videos, bar)
    except (ValueError, FileNotFoundError) as exc:
        bar.close()
        print(f"contourcap calibrate: error: {exc}", file=sys.stderr)
        return 2
    bar.close()
    for name, r in report.items():
        if name.startswith("_"):
            continue
        if r["used"]:
            extra = " ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in r.items() if k != "used")
            print(f"{name}: ok {extra}")
        else:
            print(f"{name}: NOT CALIBRATED: {r['reason']}")
    if "_overall" in report and np.isfinite(report["_overall"]["rms_px"]):
        print(f"overall RMS reprojection error: {report['_overall']['rms_px']:.3f} px")
    try:
        if args.report:
            write_text_atomic(args.report, json.dumps(report, indent=2))
        if cams:
            save_calibration(args.out, cams)
            print(f"wrote {args.out} ({len(cams)} camera(s))")
    except OSError as exc:
        print(f"contourcap calibrate: error: cannot write {exc.filename}: {exc.strerror}", file=sys.stderr)
        return 2
    failed = [n for n, r in report.items() if not n.startswith("_") and not r["used"]]
    if failed:
        print(f"left out: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0
