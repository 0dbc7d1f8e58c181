"""``contourcap segment SESSION OUT``: segment every camera of a session for inspection.

Per camera: a background model is learned from the camera's background media (up to
``--background-frames`` frames) or, lacking those, from the temporal median of up to
``--median-frames`` frames strided over the session; then every frame is segmented with
:func:`segmentation.segment_frame` and, every ``--every`` frames, written as PNGs::

    OUT/<camera>/silhouette_000123.png   0/255
    OUT/<camera>/edges_000123.png        0/255
    OUT/<camera>/dist_sil_000123.png     quantised distance to the silhouette, full image
    OUT/<camera>/dist_edge_000123.png    quantised distance to the edges (value * resolution = px)
    OUT/<camera>/background.npz          the model (with --save-models)
    OUT/stats.json                       foreground fraction and ms per frame, per camera

A progress bar with ETA goes to stderr; the statistics are printed at the end (``--json``: one object).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from service.atomic import write_text_atomic
from service.progress import Progress

HELP = "segment a session: silhouettes, edges and distance images (PNG) plus per-camera statistics"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="session directory (with session.toml)")
    parser.add_argument("out", help="output directory (created)")
    parser.add_argument("--cameras", default=None, help="comma-separated camera names (default: all)")
    parser.add_argument("--frames", default=None, help="frame-id range START:STOP (STOP excluded; either may be empty)")
    parser.add_argument("--every", type=int, default=1, help="write PNGs every N-th frame (0: none)")
    parser.add_argument("--roi", default=None, help="process only x0,y0,x1,y1 (pixels) of every camera")
    parser.add_argument("--background-frames", type=int, default=50,
                        help="background media frames to learn from (default 50)")
    parser.add_argument("--median-frames", type=int, default=25,
                        help="session frames for a median background when there is no background media")
    parser.add_argument("--covariance", choices=("diag", "full"), default="diag")
    parser.add_argument("--max-components", type=int, default=None,
                        help="keep only the N largest foreground components (e.g. 1 for one person)")
    parser.add_argument("--no-auto-roi", action="store_true",
                        help="process the whole image (default: find the foreground at half resolution "
                             "first and process only its box)")
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1, as a worker runs)")
    parser.add_argument("--save-models", action="store_true", help="write OUT/<camera>/background.npz")
    parser.add_argument("--json", action="store_true", help="print the statistics as one JSON object")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _roi(text: str | None):
    if not text:
        return None
    try:
        vals = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--roi: expected x0,y0,x1,y1 (integers), got {text!r}") from None
    if len(vals) != 4:
        raise ValueError(f"--roi: expected x0,y0,x1,y1, got {text!r}")
    return vals


def _params(args):
    from segmentation import SegmentationParams

    if args.max_components is not None and args.max_components < 1:
        raise ValueError(f"--max-components: expected >= 1, got {args.max_components}")
    return SegmentationParams(max_components=args.max_components, auto_roi=not args.no_auto_roi)


def _full_distance_png(chamfer, which: np.ndarray) -> np.ndarray:
    """The quantised distance image pasted into the full image (truncation code outside the crop)."""
    w, h = chamfer.image_size
    full = np.full((h, w), chamfer.max_code, which.dtype)
    x0, y0 = chamfer.offset_xy
    full[y0:y0 + which.shape[0], x0:x0 + which.shape[1]] = which
    return full


def _write_png(path: Path, image: np.ndarray) -> None:
    if not cv2.imwrite(str(path), image):  # OpenCV returns False instead of raising
        raise OSError(f"{path}: cannot write this PNG")


def segment_session(session, out: Path, *, cameras=None, frames: range | None = None, every: int = 1,
                    roi=None, background_frames: int = 50, median_frames: int = 25, covariance: str = "diag",
                    save_models: bool = False, params=None, progress: Progress | None = None,
                    clock=time.perf_counter) -> dict:
    """Segment the cameras of ``session`` into ``out``; returns the statistics dict (also in stats.json)."""
    from capture.replay import read_frames
    from capture.session import SessionError
    from segmentation import segment_frame
    from service.backgrounds import learn_background

    names = list(session.camera_names if cameras is None else cameras)
    unknown = [n for n in names if n not in session.camera_names]
    if unknown:
        raise SessionError(f"{session.root}: no camera(s) {unknown} (have {list(session.camera_names)})")
    out.mkdir(parents=True, exist_ok=True)
    stats: dict = {"session": str(session.root), "cameras": {}}
    for name in names:
        cam_dir = out / name
        cam_dir.mkdir(parents=True, exist_ok=True)
        t0 = clock()
        learnt = learn_background(session, name, background_frames=background_frames,
                                  median_frames=median_frames, covariance=covariance, frames=frames)
        model, how = learnt.model, learnt.describe()
        learn_s = clock() - t0
        if save_models:
            model.save(cam_dir / "background.npz")
        fractions, ms = [], []
        chamfer = None
        for k, frame in enumerate(read_frames(session, name, frames=frames)):
            t = clock()
            try:
                seg = segment_frame(model, frame.image, roi=roi, params=params)
            except ValueError as exc:  # e.g. background media of another size than the footage
                raise SessionError(f"{session.root}: camera {name!r} frame {frame.frame_id} "
                                   f"(background: {how}): {exc}") from None
            ms.append((clock() - t) * 1e3)
            fractions.append(seg.foreground_fraction)
            chamfer = seg.chamfer
            if every > 0 and k % every == 0:
                fid = f"{frame.frame_id:06d}"
                _write_png(cam_dir / f"silhouette_{fid}.png", seg.silhouette)
                _write_png(cam_dir / f"edges_{fid}.png", seg.edges)
                _write_png(cam_dir / f"dist_sil_{fid}.png", _full_distance_png(chamfer, chamfer.silhouette_q))
                _write_png(cam_dir / f"dist_edge_{fid}.png", _full_distance_png(chamfer, chamfer.edges_q))
            if progress is not None:
                progress.advance(label=name)
        if not ms:
            raise SessionError(f"{session.root}: camera {name!r}: no frames to segment")
        fr = np.array(fractions)
        stats["cameras"][name] = {
            "background": how, "learn_s": round(learn_s, 3), "frames": len(ms),
            "foreground_fraction_mean": float(fr.mean()), "foreground_fraction_min": float(fr.min()),
            "foreground_fraction_max": float(fr.max()),
            "ms_per_frame_median": float(np.median(ms)), "ms_per_frame_mean": float(np.mean(ms)),
            "distance_resolution_px": chamfer.resolution_px, "distance_max_px": chamfer.max_distance_px,
        }
    write_text_atomic(out / "stats.json", json.dumps(stats, indent=1))
    return stats


def run(args) -> int:
    from capture.replay import count_frames, parse_frame_range
    from capture.session import SessionError, load_session
    from capture.sources import SourceError

    try:
        frames, roi = parse_frame_range(args.frames), _roi(args.roi)
        if args.every < 0:
            raise ValueError(f"--every: expected >= 0, got {args.every}")
        if args.background_frames < 1 or args.median_frames < 3:
            raise ValueError(f"--background-frames (>= 1) / --median-frames (>= 3): "
                             f"got {args.background_frames} / {args.median_frames}")
        cv2.setNumThreads(max(int(args.threads), 1))
        session = load_session(args.session, require_calibration=False)
        names = None if not args.cameras else [c.strip() for c in args.cameras.split(",") if c.strip()]
        if names == []:
            raise ValueError(f"--cameras: no camera names in {args.cameras!r}")
        selected = names or list(session.camera_names)
        counts = [count_frames(session, n, frames) for n in selected if n in session.camera_names]
        total = sum(counts) if counts and all(c is not None for c in counts) else None
        progress = Progress(total, enabled=not args.no_progress)
        try:
            stats = segment_session(session, Path(args.out), cameras=names, frames=frames, every=args.every,
                                    roi=roi, background_frames=args.background_frames,
                                    median_frames=args.median_frames, covariance=args.covariance,
                                    save_models=args.save_models, progress=progress,
                                    params=_params(args))
        finally:
            progress.close()
    except (SessionError, SourceError, ValueError, OSError) as exc:
        print(f"contourcap segment: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(stats, indent=1))
    else:
        print(f"{'camera':12s} {'frames':>6s} {'fg mean %':>9s} {'fg min %':>8s} {'fg max %':>8s} "
              f"{'ms/frame':>8s}  background")
        for name, s in stats["cameras"].items():
            print(f"{name:12s} {s['frames']:6d} {100 * s['foreground_fraction_mean']:9.2f} "
                  f"{100 * s['foreground_fraction_min']:8.2f} {100 * s['foreground_fraction_max']:8.2f} "
                  f"{s['ms_per_frame_median']:8.2f}  {s['background']}")
        print(f"written to {args.out}")
    return 0
