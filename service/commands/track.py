"""``contourcap track SESSION --out poses.jsonl``: track a recorded session offline."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from capture.media import StreamCheck, check_media
from capture.replay import count_frames, parse_frame_range
from capture.session import SessionError, load_session
from service.atomic import JsonlWriter
from tracker.body.subject import read_subject
from segmentation.clutter import ignore_masks, parse_ignore_region, session_ignore_regions
from tracker.fitting.props import parse_prop
from service.offline import background_models, session_model, session_props, summarise, track_session, warm_up_kernels
from service.smoothed import SMOOTH_WINDOW_S
from segmentation.pipeline import SegmentationParams
from tracker.fitting.scene import SceneOptions
from tracker.body.model import available_models

HELP = "track a recorded session offline and write one pose record per frame (JSONL)"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", type=Path, help="session directory (session.toml + calibration.toml)")
    parser.add_argument("--out", type=Path, required=True, help="output pose records, JSON lines")
    parser.add_argument("--model", default="knossow40", choices=available_models(), help="body model")
    parser.add_argument("--subject", type=Path, default=None, metavar="SUBJECT.toml",
                        help="the subject's body (contourcap calibrate subject); overrides session.toml's [subject]")
    parser.add_argument("--calibrate-subject", nargs="?", const="0:100", default=None, metavar="A:B",
                        help="when no subject file is given: calibrate the subject's body on frames A:B first "
                             "(default 0:100; their trusted fits, a third held out: kept only when it explains "
                             "those better), track with it and write it beside --out as OUT.subject.toml")
    parser.add_argument("--calibrate-samples", type=int, default=9, metavar="N",
                        help="--calibrate-subject: frame sets sampled, a third held out (default 9; the "
                             "calibration's CPU time grows with it)")
    parser.add_argument("--no-sliding", action="store_true", help="drop the sliding term of the contour Jacobian")
    parser.add_argument("--solver", choices=("lm", "lsq"), default="lm",
                        help="lm: analytic Levenberg–Marquardt; lsq: scipy least_squares, finite differences")
    parser.add_argument("--frames", default=None, metavar="A:B", help="frame ids A (inclusive) to B (exclusive)")
    parser.add_argument("--cameras", default=None, metavar="cam0,cam2", help="comma-separated camera subset")
    parser.add_argument("--ignore-region", action="append", default=[], metavar="CAM:x,y,w,h",
                        help="pixels of camera CAM that are never body (repeatable; adds to session.toml's "
                             "[[camera]] ignore lists)")
    parser.add_argument("--prop", action="append", default=[], metavar="x0,y0,z0,x1,y1,z1",
                        help="a world box (metres, the calibration's frame) that is never body, e.g. a chair: "
                             "clutter where the body does not cover it, and the fit keeps the body out of it "
                             "(repeatable; adds to session.toml's [[prop]] boxes; --prop=-0.3,... when it starts with -)")
    parser.add_argument("--no-scene", action="store_true",
                        help="take every foreground pixel as body (no clutter learning, no seated initialisation)")
    parser.add_argument("--no-retrack", action="store_true",
                        help="contours: fit every frame once and write it unsmoothed, as a live tracker does (default: the "
                             "scene's warm-up frames and every stretch the gate refused are fitted again backwards "
                             "from the next accepted frame)")
    parser.add_argument("--no-smooth", action="store_true",
                        help="write every frame's pose as fitted (default: each pose smoothed over a centred window "
                             "of --smooth-window seconds, never across a frame without a pose or a jump; "
                             "--no-retrack implies it)")
    parser.add_argument("--smooth-window", type=float, default=SMOOTH_WINDOW_S, metavar="SECONDS",
                        help=f"the smoothing window's length (default {SMOOTH_WINDOW_S:.3f} s: 5 frames at 30 fps, "
                             "11 at 60)")
    parser.add_argument("--allow-missing-cameras", action="store_true",
                        help="track on with the cameras that have frames when a camera's video is cut short or "
                             "corrupt (reported per camera: frames read of frames expected); default: exit 2")
    parser.add_argument("--method", choices=("contours", "blobs"), default="contours",
                        help="contours: chamfer fit of the model's contours (Knossow); blobs: coloured hull, "
                             "EM blobs and inverse kinematics (Caillette & Howard)")
    parser.add_argument("--floor-test", action="store_true",
                        help="decide shadow-like pixels with the other cameras (segmentation.floor): dark clothes "
                             "on a dark floor; offline only, so poses then differ from a lossless live run")
    parser.add_argument("--initial-pose", type=Path, default=None, metavar="POSES.jsonl",
                        help="start from the params of the first record of this pose file (else automatic)")


def read_initial_pose(path: Path, n_params: int) -> np.ndarray:
    try:
        with open(path, encoding="utf-8") as fh:
            for line in fh:
                if line.strip():
                    rec = json.loads(line)
                    p = np.asarray(rec["params"], dtype=float)
                    break
            else:
                raise ValueError("no record")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise SessionError(f"--initial-pose {path}: cannot read the first record's params ({exc})") from None
    if p.shape != (n_params,) or not np.all(np.isfinite(p)):
        raise SessionError(f"--initial-pose {path}: params has {p.size} values, the model needs {n_params}")
    return p


def median_warning(how: dict[str, str]) -> str | None:
    """One warning line when some cameras' background models are a temporal median of the take."""
    median = [n for n, h in how.items() if h == "median"]
    if not median:
        return None
    return (f"no background plate for {', '.join(median)}: their backgrounds are the temporal median of the take, "
            "which holds a subject who stays still in view as background (then lost); record the empty room "
            "with `contourcap record --background 2s`, or add background media to session.toml")


def run(args: argparse.Namespace) -> int:
    """Track; the poses go to ``OUT.partial`` (flushed per record) and replace ``OUT`` only when every
    frame was tracked (:class:`service.atomic.JsonlWriter`): a failing or interrupted run never
    truncates an existing ``OUT``, and its finished frames are kept (named on stderr)."""
    session = load_session(args.session)
    if not (args.smooth_window >= 0 and np.isfinite(args.smooth_window)):
        raise SessionError(f"--smooth-window: expected a number of seconds >= 0, got {args.smooth_window}")
    smooth_s = 0.0 if args.no_smooth or args.no_retrack else args.smooth_window
    frames = parse_frame_range(args.frames)
    cameras = None if args.cameras is None else [c.strip() for c in args.cameras.split(",") if c.strip()]
    model = session_model(session, args.model) if args.subject is None else read_subject(args.subject).body()
    from_file = (args.subject is None and session.subject_file is not None
                 and read_subject(session.subject_file).model == model.name)
    subject_name = (args.subject.name if args.subject is not None else
                    session.subject_file.name if from_file else None)
    if args.calibrate_subject is not None and subject_name is None:
        model, subject_name = _calibrated(session, args, model, cameras)
    init = None if args.initial_pose is None else read_initial_pose(args.initial_pose, model.n_params)
    names = list(session.camera_names if cameras is None else cameras)
    ignore = _ignore_masks(session, args.ignore_region)
    props = session_props(session)
    props += [parse_prop(t) for t in args.prop]
    media = check_media(session, names, frames=frames)  # unreadable, wrong size, range past the end: exit 2
    check = StreamCheck(media, allow_missing=args.allow_missing_cameras)
    for line in check.check_lengths():
        print(f"contourcap track: warning: {line}; tracking on without its missing frames", file=sys.stderr)
    t_bg = time.perf_counter()
    backgrounds, how = background_models(session, names, frames=frames)
    print(f"background models: {', '.join(f'{n}={h}' for n, h in how.items())} "
          f"({time.perf_counter() - t_bg:.1f} s)", file=sys.stderr)
    warning = median_warning(how)
    if warning:
        print(f"contourcap track: warning: {warning}", file=sys.stderr)
    total = count_frames(session, names[0], frames) if names else None
    print("tracker kernels: compiling (the first run only) or loading ...", end="", file=sys.stderr, flush=True)
    print(f" {warm_up_kernels(args.method):.1f} s", file=sys.stderr)
    records = []
    t0 = time.perf_counter()
    fitted = []  # the first fits as they are made (frames held for a refit are written later)

    def fitted_one(rec):
        fitted.append(rec["frame"])
        _progress(len(fitted), total, time.perf_counter() - t0, rec)

    out = JsonlWriter(args.out)
    try:
        for rec in track_session(session, model=model, sliding=not args.no_sliding, solver=args.solver,
                                 frames=frames, cameras=cameras, initial_params=init, backgrounds=backgrounds,
                                 method=args.method, stream_check=check, ignore=ignore, props=props,
                                 segmentation=SegmentationParams(floor_test=args.floor_test),
                                 scene=None if args.no_scene or args.method != "contours" else SceneOptions(),
                                 retrack=not args.no_retrack, smooth_s=smooth_s, on_step=fitted_one):
            if subject_name is not None:
                rec["subject"] = subject_name
            out.write(json.dumps(rec).encode())
            records.append({k: rec.get(k) for k in ("ok", "iterations", "rms_px")})
            if args.method != "contours":  # the blob tracker's records come one per frame, as fitted
                _progress(len(records), total, time.perf_counter() - t0, rec)
    except BaseException:
        kept = out.abandon()
        if kept is not None:
            print(f"\ncontourcap track: the {out.count} frames tracked before the failure are in {kept}",
                  file=sys.stderr)
        raise
    out.commit()
    for line in check.report():
        print(f"\ncontourcap track: warning: {line}", file=sys.stderr, end="")
    summary = summarise(records, time.perf_counter() - t0).as_dict()
    print(file=sys.stderr)
    print("summary: " + json.dumps(summary), file=sys.stderr)
    return 0 if summary["frames"] else 1


def _calibrated(session, args, model, cameras):
    """``--calibrate-subject``: (the body to track with, its subject file's name or None)."""
    from service.atomic import write_text_atomic
    from service.commands.calibrate_subject import auto_calibrate
    from tracker.fitting.subject_auto import AutoSubjectOptions
    from tracker.body.subject import subject_toml

    frames = parse_frame_range(args.calibrate_subject)
    if frames is None or len(frames) < 2:
        raise SessionError(f"--calibrate-subject {args.calibrate_subject!r}: expected a range A:B of at least 2 frames")
    names = list(session.camera_names if cameras is None else cameras)
    c0 = time.process_time()
    if not 3 <= args.calibrate_samples <= 64:
        raise SessionError(f"--calibrate-samples: expected 3..64, got {args.calibrate_samples}")
    options = AutoSubjectOptions.for_sample(args.calibrate_samples, span=len(frames), offers_per_set=1)
    res = auto_calibrate(session, names, frames, model, options, quiet=False,
                         segmentation=SegmentationParams(floor_test=args.floor_test))
    cpu = time.process_time() - c0
    if res is None:
        print(f"contourcap track: subject not calibrated: fewer than {options.frames} trusted frame sets in frames "
              f"{args.calibrate_subject} ({cpu:.0f} s CPU); tracking with the model's proportions", file=sys.stderr)
        return model, None
    info = {"adopted": res.adopted, "held_out_iou": [round(res.iou_current, 4), round(res.iou_calibrated, 4)],
            "frames_fitted": list(res.fit_frames), "frames_held_out": list(res.held_out_frames), "cpu_s": round(cpu, 1)}
    if not res.adopted:
        print(f"contourcap track: calibrated subject not better on held-out frames, not used: {json.dumps(info)}",
              file=sys.stderr)
        return model, None
    path = args.out.with_name(args.out.name.split(".")[0] + ".subject.toml")
    write_text_atomic(path, subject_toml(res.subject))
    print(f"contourcap track: subject calibrated, written to {path}: {json.dumps(info)}", file=sys.stderr)
    return res.fit.model, path.name


def _ignore_masks(session, texts) -> dict:
    """Camera name -> ignore mask from session.toml's ``ignore`` lists and ``--ignore-region``s."""
    regions = session_ignore_regions(session.root / "session.toml")
    for text in texts:
        name, box = parse_ignore_region(text)
        regions.setdefault(name, []).append(box)
    sizes = {n: session.camera_model(n).size for n in session.camera_names}
    return ignore_masks(sizes, regions)


def _progress(done: int, total: int | None, elapsed_s: float, rec: dict) -> None:
    rate = done / elapsed_s if elapsed_s > 0 else 0.0
    eta = f", ETA {(total - done) / rate:.0f} s" if total and rate > 0 else ""
    of = f"/{total}" if total else ""
    state = "ok" if rec.get("ok") else f"LOST ({rec.get('reason', '')})"
    print(f"\rframe {rec['frame']} ({done}{of}) {rate:.1f} fps{eta} {state}".ljust(100)[:160], end="",
          file=sys.stderr, flush=True)
