"""``contourcap run --config studio.toml``: supervise this host's workers (Ctrl-C / SIGTERM stops all)."""

from __future__ import annotations

import argparse
import logging
import socket
import sys
import threading
import time

HELP = "run this host's part of a studio: start, restart and stop its worker processes"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="studio TOML (see deploy/studio.example.toml)")
    parser.add_argument("--host", default=None, help="this host's name in the config (default: hostname)")
    parser.add_argument("--until-finished", action="store_true",
                        help="return once every worker has exited cleanly (replays)")
    parser.add_argument("--idle-exit-s", type=float, default=None,
                        help="segment/track workers exit after this long without input (replays)")
    parser.add_argument("--segment-plugin", default=None, help="module:factory replacing the segmenter")
    parser.add_argument("--fit-plugin", default=None, help="module:factory replacing the tracker")
    parser.add_argument("--start-delay-s", type=float, default=2.0,
                        help="live replay: session time 0 is this long after start (workers start up)")
    parser.add_argument("--log-level", default="INFO", type=str.upper,
                        choices=("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"))


def run(args: argparse.Namespace) -> int:
    from service.wire.bus import BusError, open_session
    from service.config import ConfigError, load_config
    from service.workers.runtime import hub_endpoint, preflight, stop_on_signals
    from service.flow.supervisor import Supervisor, plan_host

    logging.basicConfig(level=args.log_level, stream=sys.stderr,
                        format="%(asctime)s run %(levelname)s %(message)s")
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"contourcap run: {exc}", file=sys.stderr)
        return 2
    host = args.host or socket.gethostname()
    if host not in cfg.hosts:
        print(f"contourcap run: {cfg.path}: host {host!r} has no workers (hosts: {list(cfg.hosts)}); "
              "pass --host", file=sys.stderr)
        return 2
    from capture.calibration import CalibrationError
    from capture.session import SessionError

    try:
        preflight(cfg, host, fit_plugin=args.fit_plugin)
    except (ConfigError, SessionError, CalibrationError) as exc:
        print(f"contourcap run: {exc}", file=sys.stderr)
        return 2
    hub_session, hub = None, None
    if cfg.zenoh.mode == "peer":
        from dataclasses import replace

        hub = hub_endpoint(cfg)
        try:
            hub_session = open_session(replace(cfg.zenoh, listen=cfg.zenoh.listen or (hub,), connect=()))
        except BusError as exc:
            print(f"contourcap run: hub: {exc}", file=sys.stderr)
            return 2
    replay_live = cfg.delivery == "live" and any(c.backend == "replay" for c in cfg.cameras_on(host))
    epoch = time.time_ns() + int(args.start_delay_s * 1e9) if replay_live else None
    try:  # the hub session is closed whatever happens (an open one hangs the process at exit)
        specs = plan_host(cfg, args.config, host, hub=hub, epoch_ns=epoch, idle_exit_s=args.idle_exit_s,
                          segment_plugin=args.segment_plugin, fit_plugin=args.fit_plugin)
        sup = Supervisor(specs)
        sup.run(stop, until_finished=args.until_finished)
    finally:
        if hub_session is not None:
            hub_session.close()
    failed = [c.spec.name for c in sup.children if c.history and c.history[-1] not in (0, -15)]
    return 1 if failed and args.until_finished else 0


def main(argv: list[str] | None = None) -> int:
    """``python -m service.commands.run``: this command alone (fast start-up)."""
    parser = argparse.ArgumentParser(prog="contourcap run", description=HELP)
    add_args(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    from service.blas import pin_blas_threads

    pin_blas_threads()
    sys.exit(main())
