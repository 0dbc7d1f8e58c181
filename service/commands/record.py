"""``contourcap record --config studio.toml OUT``: record the studio's cameras into a session directory."""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from service.commands.argtypes import duration_s

HELP = "record the studio's cameras into a new session directory (crash-safe; png/ffv1 lossless, mjpg fast)"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", help="output session directory (must not exist or be empty)")
    parser.add_argument("--config", required=True, help="studio TOML ([studio], [trigger], [[camera]]; see capture.recorder)")
    parser.add_argument("--codec", choices=("png", "ffv1", "mjpg"), default="png",
                        help="png: lossless image files (default); ffv1: lossless video; mjpg: fast, lossy")
    parser.add_argument("--frames", type=int, default=None, help="stop after this many frames per camera")
    parser.add_argument("--duration-s", type=float, default=None, help="stop after this many seconds")
    parser.add_argument("--host", default=None, help="record only the cameras with this host in the config")
    parser.add_argument("--cameras", default=None, help="comma-separated camera names (default: all)")
    parser.add_argument("--name", default=None, help="session name (default: the studio name)")
    parser.add_argument("--segment-s", type=float, default=1.0, help="video segment length: most footage a crash can lose")
    parser.add_argument("--min-free-mb", type=float, default=64.0, help="stop with an error below this much free disk")
    parser.add_argument("--pacing", choices=("realtime", "fast"), default="realtime", help="replay cameras: pacing")
    parser.add_argument("--background", type=duration_s, default=None, metavar="DURATION",
                        help="first record DURATION (e.g. 2s) of the empty room as the session's background plate "
                             "(background/<camera>.avi), then the take; without it `track` must learn a "
                             "temporal median, which fails for a subject who stays in view")
    parser.add_argument("--resync-s", type=float, default=2.0, help="trigger box: re-anchor its clock this often")


def _check_numbers(args) -> None:
    """Options that would record nothing, or spin, are refused before anything is opened."""
    for option, value in (("--frames", args.frames), ("--duration-s", args.duration_s),
                          ("--segment-s", args.segment_s), ("--resync-s", args.resync_s)):
        if value is not None and not value > 0:  # NaN too
            raise ValueError(f"{option}: expected > 0, got {value}")


def _select(cfg, args):
    specs = list(cfg.cameras)
    if args.host is not None:
        specs = [s for s in specs if s.host == args.host]
    if args.cameras:
        wanted = [n.strip() for n in args.cameras.split(",") if n.strip()]
        unknown = sorted(set(wanted) - {s.name for s in specs})
        if unknown:
            raise ValueError(f"--cameras: {unknown} not in the config (have {[s.name for s in specs]})")
        specs = [s for s in specs if s.name in wanted]
    if not specs:
        raise ValueError("no cameras selected (check --host / --cameras)")
    return specs


def _background_take(args, cfg, specs, rec, frame_id_at, stop) -> None:
    """The empty-room take before the recording (see ``capture.background_take``)."""
    from capture.backends import open_source
    from capture.background_take import record_background

    if sys.stdin.isatty():
        input(f"background: clear the cameras' view, then press Enter to record {args.background:g} s of the "
              "empty room ")
    print(f"background: recording {args.background:g} s of the empty room (keep out of view)", file=sys.stderr)
    sources = [open_source(s, session=cfg.session, frame_id_at=frame_id_at, pacing=args.pacing, background=True)
               for s in specs]
    plates = record_background(sources, rec.root, seconds=args.background, fps=cfg.fps, stop=stop)
    rec.add_backgrounds(plates)
    print(f"background: stored {', '.join(plates.values())}; recording the take", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    from capture.recorder import Recorder, RecorderError, load_capture_config, record
    from capture.backends import open_source
    from capture.sources import SourceError
    from capture.trigger import TriggerError, start_trigger_box

    box = None
    try:
        _check_numbers(args)
        cfg = load_capture_config(args.config)
        specs = _select(cfg, args)
        stop = threading.Event()
        trigger_errors: list[str] = []
        frame_id_at = None
        if cfg.trigger == "usb" and any(s.backend == "opencv" for s in specs):
            box = start_trigger_box(cfg.fps, stop=stop, resync_s=args.resync_s,
                                    on_lost=lambda exc: trigger_errors.append(str(exc)))
            frame_id_at = box.frame_id_at
        sources = [open_source(s, session=cfg.session, frame_id_at=frame_id_at, pacing=args.pacing) for s in specs]
        rec = Recorder(
            args.out, name=args.name or cfg.name, fps=cfg.fps, cameras=[s.name for s in specs], codec=args.codec,
            calibration=cfg.calibration, segment_s=args.segment_s, min_free_bytes=int(args.min_free_mb * 2**20),
        )
        if args.background is not None:
            _background_take(args, cfg, specs, rec, frame_id_at, stop)
        timer = threading.Timer(args.duration_s, stop.set) if args.duration_s else None
        old = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                old[sig] = signal.signal(sig, lambda *_: stop.set())
        try:
            if timer:
                timer.start()
            summary = record(sources, rec, max_frames=args.frames, stop=stop)
        finally:
            if timer:
                timer.cancel()
            for sig, handler in old.items():
                signal.signal(sig, handler)
    except (RecorderError, TriggerError, SourceError, ValueError) as exc:
        print(f"record: error: {exc}", file=sys.stderr)
        return 2
    finally:
        if box is not None:
            stop.set()
            try:
                box.stop()
            except TriggerError as exc:
                print(f"record: warning: {exc}", file=sys.stderr)
            box.close()
    failed = False
    for cam in summary.cameras:
        line = f"{cam.name}: {cam.frames} frames, {cam.dropped} dropped, {cam.rejected} rejected"
        if cam.error:
            failed = True
            line += f"; stopped: {cam.error}"
        print(line)
    for err in trigger_errors:
        failed = True
        print(f"trigger box stopped the recording: {err}")
    print(f"session written to {summary.root}")
    return 1 if failed else 0
