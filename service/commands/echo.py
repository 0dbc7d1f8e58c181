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
    parser.add_argument("--stats", action="store_true",
                        help="every --stats-every seconds and at exit, print on stderr poses/s, ok, latency (capture to publish) and fit time p50/p99, what was rejected (malformed) and evicted (too slow) here, and "
                             "the rejected/evicted/dropped counters the studio's workers report on status/*; "
                             "no line per pose")
    parser.add_argument("--stats-every", type=float, default=5.0, help="seconds between --stats lines")



# status counters that say a worker refused or lost input (shown by --stats)
STAT_WORDS = ("rejected", "bad", "evicted", "dropped", "overflow", "oversized", "mismatched_key", "unknown")


def format_stats(own: dict, workers: dict[str, dict]) -> str:
    """One line: this client's counters, then each worker's non-zero refusal/loss counters."""
    from service.text import printable

    parts = [f"echo: received {own['received']}, rejected {own['rejected']}, evicted {own['evicted']}"]
    for comp in sorted(workers):
        vals = {k: v for k, v in workers[comp].items() if any(w in k for w in STAT_WORDS) and v}
        text = ", ".join(f"{printable(k, limit=40)} {v:g}" for k, v in sorted(vals.items())) or "nothing refused"
        parts.append(f"{printable(comp, limit=40)}: {text}")
    return "stats  " + "; ".join(parts)


class PoseStats:
    """Running figures of received poses: rate, ok fraction, ``latency_ms`` and ``fit_ms`` percentiles.

    Parameters
    ----------
    clock : callable () -> float
        Seconds (the rate is poses over the time since the first pose).
    window : int
        Percentiles over the last ``window`` poses.
    """

    def __init__(self, clock, *, window: int = 10_000) -> None:
        import collections

        self.clock, self.n, self.ok, self.first = clock, 0, 0, None
        self.latency = collections.deque(maxlen=window)
        self.fit = collections.deque(maxlen=window)

    def add(self, rec) -> None:
        """Count one pose record."""
        now = self.clock()
        self.first = now if self.first is None else self.first
        self.n += 1
        self.ok += bool(rec.ok)
        for key, values in (("latency_ms", self.latency), ("fit_ms", self.fit)):
            v = rec.get(key)
            if v is not None:
                values.append(float(v))

    def line(self) -> str:
        """One summary line."""
        import numpy as np

        span = self.clock() - self.first if self.first is not None else 0.0
        rate = (self.n - 1) / span if self.n > 1 and span > 0 else 0.0

        def pct(values) -> str:
            if not values:
                return "n/a"
            p50, p99 = np.percentile(np.asarray(values), [50, 99])
            return f"p50 {p50:.1f} ms, p99 {p99:.1f} ms"

        ok = f"{100.0 * self.ok / self.n:.0f} %" if self.n else "n/a"
        return (f"{self.n} poses, {rate:.1f} poses/s, {ok} ok; latency {pct(self.latency)}; "
                f"fit {pct(self.fit)}")


def format_pose(rec) -> str:
    """One human-readable line for a pose record (received strings printed escaped)."""
    from service.text import printable

    parts = [f"frame {rec.frame:6d}", "ok  " if rec.ok else "LOST", f"cams {printable(rec.get('cameras', '?'))}"]
    if rec.get("rms_px") is not None:
        parts.append(f"rms {rec.get('rms_px'):.2f} px")
    if rec.get("latency_ms") is not None:
        parts.append(f"lat {rec.get('latency_ms'):.1f} ms")
    pelvis = rec.get("joints", {}).get("pelvis")
    if pelvis is not None:
        parts.append("pelvis ({:+.3f} {:+.3f} {:+.3f}) m".format(*pelvis))
    if not rec.ok:
        parts.append(f"reason: {printable(rec.get('reason'))}")
    return "  ".join(parts)


def run(args: argparse.Namespace) -> int:
    import time

    from service.wire.bus import BusError, Inbox, Keys, open_session
    from service.config import ConfigError
    from service.wire.records import PoseRecord, StatusMessage
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
    inbox = statuses = None
    workers: dict[str, dict] = {}
    n, last = 0, time.monotonic()
    last_stats = last

    def show_stats() -> None:
        for got in statuses.drain():
            workers[got.message.component] = dict(got.message.stats)
        own = {"received": inbox.received, "rejected": inbox.bad + statuses.bad, "evicted": inbox.dropped}
        print(format_stats(own, workers), file=sys.stderr, flush=True)

    stats = PoseStats(time.monotonic) if args.stats else None
    stats_at = time.monotonic() + args.stats_every
    try:
        inbox = Inbox(session, Keys(studio).pose, PoseRecord.from_bytes, mode="live", depth=256)
        if args.stats:
            statuses = Inbox(session, Keys(studio).status("*"), StatusMessage.from_bytes, mode="live", depth=64)
        while not stop.is_set() and (args.count is None or n < args.count):
            if statuses is not None and time.monotonic() - last_stats >= args.stats_every:
                last_stats = time.monotonic()
                show_stats()
            got = inbox.recv(0.1)
            if stats is not None and stats.n and time.monotonic() >= stats_at:
                stats_at = time.monotonic() + args.stats_every
                print(stats.line(), file=sys.stderr, flush=True)
            if got is None:
                if args.idle_exit_s is not None and time.monotonic() - last > args.idle_exit_s:
                    break
                continue
            last = time.monotonic()
            rec = got.message
            if stats is not None:
                stats.add(rec)
            else:
                print(rec.to_bytes().decode() if args.json else format_pose(rec), flush=True)
            if out is not None:
                out.write(rec.to_bytes() + b"\n")
            n += 1
    except BrokenPipeError:  # `contourcap echo | head`
        pass
    finally:
        if out is not None:
            out.close()
        if statuses is not None:
            show_stats()
            statuses.close()
        if stats is not None:
            print(stats.line(), file=sys.stderr, flush=True)
        if inbox is not None:
            if inbox.dropped or inbox.bad:
                print(f"contourcap echo: {inbox.dropped} poses dropped (too slow), {inbox.bad} bad messages",
                      file=sys.stderr)
            inbox.close()
        session.close()
    return 0
