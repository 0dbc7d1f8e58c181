"""``contourcap review SESSION POSES.jsonl --out review.mp4 [--sheet sheet.png]``: see a take."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "draw pose records over every camera's images: a review video and/or a contact sheet"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", type=Path, help="session directory (session.toml + calibration.toml)")
    parser.add_argument("poses", type=Path, help="pose records, JSON lines (contourcap track --out)")
    parser.add_argument("--out", type=Path, default=None, metavar="review.mp4",
                        help="review video (.mp4: mp4v, .avi: MJPG), cameras tiled")
    parser.add_argument("--sheet", type=Path, default=None, metavar="sheet.png",
                        help="contact sheet PNG of evenly spaced frames, each camera cropped to the person")
    parser.add_argument("--sheet-frames", type=int, default=6, metavar="N", help="frames on the sheet (default 6)")
    parser.add_argument("--frames", default=None, metavar="A:B", help="frame ids A (inclusive) to B (exclusive)")
    parser.add_argument("--names", action="store_true", help="write the joint names")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from capture.replay import parse_frame_range
    from capture.session import SessionError, load_session
    from service.progress import Progress
    from service.review import ReviewError, load_records, write_review
    from tracker.body.model import ModelError

    if args.out is None and args.sheet is None:
        print("contourcap review: error: give --out review.mp4 and/or --sheet sheet.png", file=sys.stderr)
        return 2
    if args.sheet_frames < 1:
        print("contourcap review: error: --sheet-frames must be >= 1", file=sys.stderr)
        return 2
    bar = Progress(unit="frames", enabled=not args.quiet)
    try:
        session = load_session(args.session)
        frames = parse_frame_range(args.frames)
        records = load_records(args.poses)
        summary = write_review(session, records, video=args.out, sheet=args.sheet, frames=frames, names=args.names,
                               sheet_frames=args.sheet_frames, progress=bar, source=str(args.poses))
    except (SessionError, ReviewError, ModelError, ValueError, OSError) as exc:
        bar.close()
        print(f"contourcap review: error: {exc}", file=sys.stderr)
        return 2
    bar.close()
    what = [p for p in (summary.video, summary.sheet) if p]
    print(f"reviewed {summary.frames} frames ({summary.with_record} with a record, {summary.ok} ok): "
          f"{', '.join(what)}")
    return 0
