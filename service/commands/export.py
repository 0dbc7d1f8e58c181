"""``contourcap export poses.jsonl --bvh out.bvh --trc out.trc --c3d out.c3d --csv out.csv``: convert recorded
pose records to animation (BVH) and marker (TRC, C3D, CSV) files."""

from __future__ import annotations

import argparse
import sys

from service.commands.argtypes import positive_float

HELP = "export recorded poses (JSONL) to BVH, TRC (OpenSim), C3D and CSV"

UP_HELP = ("up axis of the files: 'y' writes tracker (x, y, z) as (x, z, -y), a -90 deg rotation about X; "
           "'z' keeps the tracker's Z-up world. Default: y for BVH and TRC (what Blender and OpenSim expect), "
           "z for C3D and CSV (the lab convention and the pose record's)")


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("poses", help="pose records, one JSON object per line (contourcap track / echo --out)")
    parser.add_argument("--bvh", default=None, help="BVH file to write (metres; one frame per frame id at the "
                        "session's rate: frame ids without an ok pose HOLD the previous pose)")
    parser.add_argument("--trc", default=None, help="TRC marker file (OpenSim, Pose2Sim): joint centres as markers")
    parser.add_argument("--c3d", default=None, help="C3D marker file (C3D frame = pose frame id + 1)")
    parser.add_argument("--csv", default=None, help="CSV of joint centres, one row per pose record")
    parser.add_argument("--units", choices=("mm", "m"), default="mm", help="units of TRC, C3D and CSV (default mm)")
    parser.add_argument("--up", choices=("z", "y"), default=None, help=UP_HELP)
    parser.add_argument("--smooth", default="off", metavar="off|one-euro[:MIN_CUTOFF,BETA]",
                        help="1-euro smoothing of joints and pose parameters (default off; one-euro alone: "
                             "MIN_CUTOFF 1.0 Hz, BETA 10); not-ok frames reset the filter")
    parser.add_argument("--model", default=None, help="body model for BVH (default: the records' 'model')")
    parser.add_argument("--height-m", type=float, default=None, help="subject height the tracker used")
    parser.add_argument("--session", default=None, help="take height/segment lengths from this session")
    parser.add_argument("--skip-bad", action="store_true",
                        help="skip (and report) malformed lines instead of refusing the file; a last line cut "
                             "short (a take interrupted by a kill or a power cut) is always skipped and reported")
    parser.add_argument("--fps", type=positive_float, default=None, help="frame rate (default: from the timestamps)")


def model_for_export(args, records):
    """The body model the records were fitted with, sized from --height-m or --session (else the model default)."""
    from service.export import ExportError
    from tracker.body.model import ModelError, load_model

    name = args.model or next((r.get("model") for r in records if r.get("model")), "knossow40")
    height, lengths = args.height_m, None
    if args.height_m is None and not args.session:
        from tracker.body.model import DEFAULT_HEIGHT_M

        print(f"contourcap export: no --session or --height-m: the BVH skeleton assumes a {DEFAULT_HEIGHT_M:g} m "
              "subject (its bone lengths scale with it; give the session the poses were tracked from)",
              file=sys.stderr)
    if args.session:
        from capture.session import SessionError, load_session

        try:
            s = load_session(args.session, require_calibration=False)
        except SessionError as exc:
            raise ExportError(str(exc)) from None
        height, lengths = height or s.height_m, s.segment_lengths
    try:
        return load_model(name, height_m=height, segment_lengths=lengths)
    except ModelError as exc:
        raise ExportError(f"--model: {exc}") from None


def run(args: argparse.Namespace) -> int:
    from service.export import ExportError, write_bvh
    from service.outputs.posefile import read_pose_file

    if not (args.bvh or args.trc or args.c3d or args.csv):
        print("contourcap export: give at least one of --bvh, --trc, --c3d, --csv", file=sys.stderr)
        return 2
    try:
        from tracker.body.filters import parse_one_euro

        smooth = parse_one_euro(args.smooth)
    except ValueError as exc:
        print(f"contourcap export: {exc}", file=sys.stderr)
        return 2
    try:
        pose_file = read_pose_file(args.poses, skip_bad=args.skip_bad)
        if pose_file.skipped:
            print(f"contourcap export: {pose_file.report()}", file=sys.stderr)
        records = pose_file.records
        if not records:
            raise ExportError(f"{args.poses}: no pose records")
        if smooth is not None:
            from service.outputs.smoothing import smooth_records
            from service.outputs.timeline import make_timeline

            fps = make_timeline(records, fps=args.fps, where=args.poses).fps
            records = smooth_records(records, *smooth, fps)
        if args.bvh:
            if not any(r.ok and r.get("params") for r in records):
                raise ExportError(f"{args.poses}: no ok pose with params in its {len(records)} records "
                                  "(every frame was lost): nothing to animate")
            out = write_bvh(args.bvh, model_for_export(args, records), records, fps=args.fps, up=args.up or "y")
            print(f"wrote {out.path}: {out.frames} frames at {out.fps:.2f} fps (ids {out.first_frame}.."
                  f"{out.first_frame + out.frames - 1}), {out.joints} joints, {out.up.upper()} up "
                  f"({out.repeated} frames without an ok pose hold the previous one)")
        if args.trc or args.c3d or args.csv:
            _markers(args, records)
    except ExportError as exc:
        print(f"contourcap export: {exc}", file=sys.stderr)
        return 2
    return 0


def _markers(args, records) -> None:
    from service.outputs.timeline import make_timeline, marker_array, marker_names
    from tracker.body.joint_frames import axes_for

    tl = make_timeline(records, fps=args.fps, where=args.poses)
    names = marker_names(records, args.poses)
    scale = 1000.0 if args.units == "mm" else 1.0
    gaps = int(tl.n_rows - tl.ok.sum())
    what = (f"{len(names)} markers, {tl.n_rows} frames (ids {tl.frames[0]}..{tl.frames[-1]}) at {tl.fps:.2f} fps, "
            f"{gaps} gaps, {args.units}")
    for kind, path, default_up in (("trc", args.trc, "y"), ("c3d", args.c3d, "z"), ("csv", args.csv, "z")):
        if not path:
            continue
        up = args.up or default_up
        markers = marker_array(records, tl, names, axes=axes_for(up), scale=scale)
        if kind == "trc":
            from service.outputs.trc import write_trc

            write_trc(path, tl, names, markers, units=args.units)
        elif kind == "c3d":
            from service.outputs.c3d import write_c3d

            write_c3d(path, tl, names, markers, units=args.units, up=up)
        else:
            from service.outputs.csv import write_csv

            write_csv(path, tl, names, markers)
        if kind == "csv":
            print(f"wrote {path}: {len(names)} joints, {int((tl.record >= 0).sum())} rows (one per record), "
                  f"{args.units}, {up.upper()} up")
        else:
            print(f"wrote {path}: {what}, {up.upper()} up")
