"""``contourcap export poses.jsonl --bvh out.bvh``: convert recorded pose records to BVH."""

from __future__ import annotations

import argparse
import sys

HELP = "export recorded poses (JSONL) to BVH for Blender and other animation tools"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("poses", help="pose records, one JSON object per line (contourcap track / echo --out)")
    parser.add_argument("--bvh", required=True, help="BVH file to write")
    parser.add_argument("--model", default=None, help="body model (default: the records' 'model')")
    parser.add_argument("--height-m", type=float, default=None, help="subject height the tracker used")
    parser.add_argument("--session", default=None, help="take height/segment lengths from this session")
    parser.add_argument("--fps", type=float, default=None, help="frame rate (default: from the timestamps)")


def run(args: argparse.Namespace) -> int:
    from service.export import ExportError, read_pose_records, write_bvh

    try:
        records = read_pose_records(args.poses)
        if not records:
            raise ExportError(f"{args.poses}: no pose records")
        from tracker.body.model import ModelError, load_model

        name = args.model or next((r.get("model") for r in records if r.get("model")), "knossow40")
        height, lengths = args.height_m, None
        if args.session:
            from capture.session import SessionError, load_session

            try:
                s = load_session(args.session, require_calibration=False)
            except SessionError as exc:
                raise ExportError(str(exc)) from None
            height, lengths = height or s.height_m, s.segment_lengths
        try:
            model = load_model(name, height_m=height, segment_lengths=lengths)
        except ModelError as exc:
            raise ExportError(f"--model: {exc}") from None
        out = write_bvh(args.bvh, model, records, fps=args.fps)
    except ExportError as exc:
        print(f"contourcap export: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out.path}: {out.frames} frames at {out.fps:.2f} fps, {out.joints} joints "
          f"({out.repeated} lost frames hold the previous pose)")
    return 0
