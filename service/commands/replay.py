"""``contourcap replay SESSION``: replay a session's cameras and print per-camera frame rates."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

HELP = "replay a recorded session (no hardware) and print per-camera frames, drops and fps"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("session", help="session directory (with session.toml)")
    parser.add_argument("--cameras", default=None, help="comma-separated camera names (default: all)")
    parser.add_argument("--pacing", choices=("fast", "realtime"), default="fast",
                        help="fast: decode throughput; realtime: at the session's fps")
    parser.add_argument("--frames", default=None, help="frame-id range START:STOP (STOP excluded; either may be empty)")
    parser.add_argument("--background", action="store_true", help="replay the background media instead")
    parser.add_argument("--json", action="store_true", help="print one JSON object")


def _replay_camera(session, name, args, out: dict) -> None:
    from capture.replay import ReplaySource, parse_frame_range
    from capture.sources import EndOfStream, SourceError

    n, first, last, t0 = 0, None, None, time.perf_counter()
    try:
        with ReplaySource(session, name, pacing=args.pacing, frames=parse_frame_range(args.frames), background=args.background) as src:
            while True:
                try:
                    frame = src.read()
                except EndOfStream:
                    break
                n += 1
                first = frame.frame_id if first is None else first
                last = frame.frame_id
        error = None
    except SourceError as exc:
        error = str(exc)
    except Exception as exc:  # reported per camera: a thread's exception would otherwise be lost
        error = f"unexpected {type(exc).__name__}: {exc}"
    elapsed = time.perf_counter() - t0
    out[name] = {
        "frames": n, "first_frame_id": first, "last_frame_id": last,
        "dropped": 0 if first is None else last - first + 1 - n,
        "seconds": round(elapsed, 4), "fps": round(n / elapsed, 2) if elapsed > 0 else None, "error": error,
    }


def _dropped_against_all(results: dict) -> None:
    """Count each camera's drops over the span of frame ids *any* camera delivered, so a camera whose
    stream ends early (a cut or corrupt file) shows its missing tail (``missing_at_end``) as dropped."""
    firsts = [r["first_frame_id"] for r in results.values() if r["first_frame_id"] is not None]
    lasts = [r["last_frame_id"] for r in results.values() if r["last_frame_id"] is not None]
    for r in results.values():
        if not firsts or r["error"] and r["frames"] == 0:
            r["missing_at_end"] = 0
            continue
        lo, hi = min(firsts), max(lasts)
        r["dropped"] = hi - lo + 1 - r["frames"]
        r["missing_at_end"] = hi - (r["last_frame_id"] if r["last_frame_id"] is not None else lo - 1)


def run(args: argparse.Namespace) -> int:
    from capture.replay import parse_frame_range
    from capture.session import SessionError, load_session

    try:
        session = load_session(args.session, require_calibration=False)
        names = session.camera_names
        if args.cameras:
            names = tuple(n.strip() for n in args.cameras.split(",") if n.strip())
            if not names:
                raise ValueError(f"--cameras: no camera names in {args.cameras!r}")
            for n in names:
                session.camera(n)
        parse_frame_range(args.frames)
    except (SessionError, ValueError) as exc:
        print(f"replay: error: {exc}", file=sys.stderr)
        return 2
    results: dict = {}
    threads = [threading.Thread(target=_replay_camera, args=(session, n, args, results)) for n in names]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    _dropped_against_all(results)
    report = {"session": str(session.root), "fps_nominal": session.fps, "pacing": args.pacing,
              "cameras": {n: results[n] for n in names}}
    if args.json:
        print(json.dumps(report))
    else:
        for n in names:
            r = results[n]
            tail = f"  ERROR: {r['error']}" if r["error"] else ""
            cut = f", {r['missing_at_end']} of them after its last frame: cut short?" if r["missing_at_end"] else ""
            print(f"{n}: {r['frames']} frames ({r['dropped']} dropped{cut}) in {r['seconds']:.3f} s = {r['fps']} fps{tail}")
    from service.text import printable

    for n in names:
        if results[n]["error"]:
            print(f"contourcap replay: camera {n}: {printable(results[n]['error'], limit=300)}", file=sys.stderr)
    return 1 if any(r["error"] for r in results.values()) else 0
