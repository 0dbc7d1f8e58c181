"""``contourcap calibrate subject SESSION --frames A:B --out subject.toml``: the subject's body.

The frames are tracked as ``contourcap track`` does (clutter learned, seated or standing start);
``--samples`` frame sets spread over the range's second half (after the clutter has been learned),
whose fits the scene tracker trusts, are handed with their body silhouettes to
``tracker.fitting.subject_size.estimate_segment_lengths`` (segment lengths, and unless
``--lengths-only`` the hip and shoulder widths and the limb and trunk radii); the result is written as a subject
file (``tracker.body.subject``), which ``contourcap track --subject`` and session.toml's
``[subject] file`` use.  Exit status 0 when written, 1 when no frame could be used, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from capture.replay import count_frames, iter_frame_sets, parse_frame_range
from capture.session import SessionError, image_frame_ids, load_session
from segmentation.pipeline import SegmentationParams
from service.offline import background_models, floor_test, session_model, session_props
from tracker.body.model import ModelError, available_models
from tracker.body.subject import Subject, write_subject
from tracker.fitting.scene import SceneTracker
from tracker.fitting.subject_auto import AutoSubjectOptions, SampleCalibration, SubjectSample, calibrate_sample
from tracker.fitting.subject_size import RADIUS_ORDER, WIDTH_ORDER, estimate_segment_lengths
from tracker.fitting.tracking import Tracker


def add_subject_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("session", type=Path, help="session directory")
    p.add_argument("--frames", default="0:100", metavar="A:B", help="frame ids to calibrate on (default 0:100)")
    p.add_argument("--out", type=Path, required=True, help="subject file to write (TOML)")
    p.add_argument("--model", default="knossow40", choices=available_models(), help="body model")
    p.add_argument("--samples", type=int, default=6, help="frame sets the lengths are fitted to (default 6)")
    p.add_argument("--lengths-only", action="store_true",
                   help="fit the segment lengths only (not the hip/shoulder widths and the radii)")
    p.add_argument("--score-inset", type=float, default=0.0, metavar="PX",
                   help="scoring views' outline inset in pixels (ScoreViews.inset_px; 0.35 draws the model "
                        "unbiased, docs/subject_calibration.md round 15; default 0)")
    p.add_argument("--quiet", action="store_true", help="no progress")


def track_range(session, names, frames: range, model, on_fit, *, quiet: bool = True, backgrounds=None,
                segmentation: SegmentationParams | None = None):
    """Track ``frames`` as ``contourcap track`` does (``SceneTracker``: clutter learned, the session's
    props, seated or standing start) and call ``on_fit(frame_id, record, silhouettes)`` for every
    fit of the range's second half (after the clutter is learned) the scene tracker trusts, with its
    clutter-cut silhouettes (camera -> mask); returns the tracker's model (the start may resize it).
    ``backgrounds``: camera name -> BackgroundModel (None: ``service.offline.background_models``);
    ``segmentation``: as the track's (its ``floor_test`` too: the silhouettes fitted are the track's)."""
    if backgrounds is None:
        backgrounds, _ = background_models(session, names, frames=frames)
    cams = [session.camera_model(n) for n in names]
    tracker = Tracker(model, cams)
    props = session_props(session)
    st = SceneTracker(tracker, backgrounds, props=props, segmentation=segmentation,
                      floor=floor_test(cams, backgrounds, segmentation))
    half = frames.start + len(frames) // 2
    for fid, group in iter_frame_sets(session, cameras=names, frames=frames):
        rec = st.step(fid, next(iter(group.values())).timestamp_ns, {n: f.image for n, f in group.items()})
        if fid >= half and rec.get("params") is not None and st.trusted(rec):
            on_fit(fid, rec, {n: s.silhouette.copy() for n, s in st.last_segmentation.items()})
        if not quiet:
            print(f"\rtracking frame {fid}", end="", file=sys.stderr, flush=True)
    if not quiet:
        print(file=sys.stderr)
    return st.tracker.model


def auto_calibrate(session, names, frames: range, model, options: AutoSubjectOptions, *,
                   quiet: bool = True, backgrounds=None,
                   segmentation: SegmentationParams | None = None) -> SampleCalibration | None:
    """``contourcap track --calibrate-subject``: the trusted fits of ``frames`` (:func:`track_range`;
    a range past the take's end is cut to the take, so that its second half is the take's)
    sampled (``tracker.fitting.subject_auto.SubjectSample``, at most ``options.frames`` sets spread in
    time and pose), a subject fitted to them and judged on the held-out ones (``calibrate_sample``:
    check ``adopted``); None when fewer than ``options.frames`` sets could be sampled (as the live
    calibration, which starts only on a full sample: a body fitted to a few sets of nearly one pose
    explains their pose errors too).  ``backgrounds``, ``segmentation``: as :func:`track_range`'s."""
    frames = within_take(session, names, frames)
    sample = SubjectSample(model, options.frames, options.min_gap)
    fitted = track_range(session, names, frames, model,
                         lambda fid, rec, sils: sample.offer(fid, rec["params"], sils), quiet=quiet,
                         backgrounds=backgrounds, segmentation=segmentation)
    if len(sample) < max(2, int(options.frames)):
        return None
    first, last = frames.start, frames.stop
    return calibrate_sample(fitted, [session.camera_model(n) for n in names], sample.sets(), options,
                            where=f"contourcap track --calibrate-subject, frames {first}:{last}")


def within_take(session, names, frames: range) -> range:
    """``frames`` cut to end after the last frame id of the take's first camera (image files present,
    or a video's frame count); unchanged when that is unknown or the range holds none of the take."""
    if not names:
        return frames
    cam = session.camera(names[0])
    if cam.images is not None:
        ids = image_frame_ids(cam.images)
        end = int(ids.max()) + 1 if ids.size else None
    else:
        end = count_frames(session, names[0])
    return frames if end is None or frames.stop <= end or frames.start >= end else range(frames.start, end)


def run_subject(args: argparse.Namespace) -> int:
    try:
        session = load_session(args.session)
        frames = parse_frame_range(args.frames)
        if frames is None or len(frames) < 2:
            raise ValueError(f"--frames {args.frames!r}: expected a range A:B of at least 2 frames")
        if args.samples < 1:
            raise ValueError(f"--samples: expected >= 1, got {args.samples}")
        model = session_model(session, args.model)
        names = list(session.camera_names)
        half = frames.start + len(frames) // 2
        want = set(np.linspace(half, frames.stop - 1, args.samples).round().astype(int).tolist())
        poses, sils = [], []

        def take(fid, rec, silhouettes):
            if fid in want or len(poses) < 1:
                poses.append(np.asarray(rec["params"], float))
                sils.append(silhouettes)

        fitted_model = track_range(session, names, frames, model, take, quiet=args.quiet)
        if not poses:
            print(f"contourcap calibrate subject: no trusted fit in frames {args.frames}; try other frames",
                  file=sys.stderr)
            return 1
        more = {} if args.lengths_only else {"widths": WIDTH_ORDER, "radii": RADIUS_ORDER}
        fit = estimate_segment_lengths(fitted_model, [session.camera_model(n) for n in names], poses, sils,
                                       inset_px=float(args.score_inset), **more)
        subject = Subject(fitted_model.name, fitted_model.height_m, fit.segment_lengths,
                          f"contourcap calibrate subject, frames {args.frames}, {len(poses)} frame sets, "
                          f"silhouette IoU {fit.iou_before:.3f} -> {fit.iou_after:.3f}", fit.widths, fit.radius_scale)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_subject(args.out, subject)
    except (SessionError, ModelError, ValueError, OSError) as exc:
        print(f"contourcap calibrate subject: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps({"out": str(args.out), "frames_used": len(poses), "iou_before": round(fit.iou_before, 4),
                      "iou_after": round(fit.iou_after, 4),
                      "segment_lengths_m": {k: round(v, 4) for k, v in fit.segment_lengths.items()},
                      "widths_m": {k: round(v, 4) for k, v in fit.widths.items()},
                      "radius_scale": {k: round(v, 4) for k, v in fit.radius_scale.items()}}))
    return 0
