"""``contourcap echo``: print poses live, one line each (``--json``: the pose record itself)."""

from __future__ import annotations

import argparse
import sys
import threading

HELP = "print live poses from a studio (one line per pose; --json for the raw records)"


def add_args(parser: argparse.ArgumentParser) -> None:
    from service.workers.runtime import add_connection_args

    add_connection_args(parser)
    parser.add_argument("--json", action="store_true", help="print each pose record as one JSON line")
    parser.add_argument("--count", type=int, default=None, help="exit after this many poses")
    parser.add_argument("--idle-exit-s", type=float, default=None, help="exit after this long without a pose")
    parser.add_argument("--out", default=None, help="also append the records to this JSONL file")


def format_pose(rec) -> str:
    """One human-readable line for a pose record."""
    parts = [f"frame {rec.frame:6d}", "ok  " if rec.ok else "LOST", f"cams {rec.get('cameras', '?')}"]
    if rec.get("rms_px") is not None:
        parts.append(f"rms {rec.get('rms_px'):.2f} px")
    if rec.get("latency_ms") is not None:
        parts.append(f"lat {rec.get('latency_ms'):.1f} ms")
    pelvis = rec.get("joints", {}).get("pelvis")
    if pelvis is not None:
        parts.append("pelvis ({:+.3f} {:+.3f} {:+.3f}) m".format(*pelvis))
    if not rec.ok:
        parts.append(f"reason: {rec.get('reason')}")
    return "  ".join(parts)


def run(args: argparse.Namespace) -> int:
    import time

    from service.wire.bus import BusError, Inbox, Keys, open_session
    from service.config import ConfigError
    from service.wire.records import PoseRecord
    from service.workers.runtime import client_settings, stop_on_signals

    stop = threading.Event()
    stop_on_signals(stop)
    out = None
    try:
        settings, studio = client_settings(args)
        out = open(args.out, "ab") if args.out else None  # before the session: nothing to leave open
        session = open_session(settings)
    except (ConfigError, BusError, OSError) as exc:
        if out is not None:
            out.close()
        what = f"--out: {exc}" if isinstance(exc, OSError) else str(exc)
        print(f"contourcap echo: {what}", file=sys.stderr)
        return 2
    inbox = None
    n, last = 0, time.monotonic()
    try:
        inbox = Inbox(session, Keys(studio).pose, PoseRecord.from_bytes, mode="live", depth=256)
        while not stop.is_set() and (args.count is None or n < args.count):
            got = inbox.recv(0.1)
            if got is None:
                if args.idle_exit_s is not None and time.monotonic() - last > args.idle_exit_s:
                    break
                continue
            last = time.monotonic()
            rec = got.message
            print(rec.to_bytes().decode() if args.json else format_pose(rec), flush=True)
            if out is not None:
                out.write(rec.to_bytes() + b"\n")
            n += 1
    except BrokenPipeError:  # `contourcap echo | head`
        pass
    finally:
        if out is not None:
            out.close()
        if inbox is not None:
            if inbox.dropped or inbox.bad:
                print(f"contourcap echo: {inbox.dropped} poses dropped (too slow), {inbox.bad} bad messages",
                      file=sys.stderr)
            inbox.close()
        session.close()
    return 0
