"""``contourcap router``: a zenoh session in router mode for multi-host studios (zenohd replacement)."""

from __future__ import annotations

import argparse
import logging
import sys
import threading

HELP = "run a zenoh router (TLS, user/password, ACL from the studio config or a zenoh JSON5 file)"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, help="studio TOML: uses its [router] table")
    parser.add_argument("--zenoh-config", default=None, help="a zenoh JSON5 file (e.g. deploy/zenoh/router-tls.json5)")
    parser.add_argument("--listen", action="append", default=None,
                        help="endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable; overrides the files)")
    parser.add_argument("--stats-s", type=float, default=10.0, help="log connected sessions every so often")


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from service.wire.bus import BusError, ZenohSettings, open_session
    from service.config import ConfigError, load_config
    from service.workers.runtime import stop_on_signals

    logging.basicConfig(level="INFO", stream=sys.stderr, format="%(asctime)s router %(levelname)s %(message)s")
    log = logging.getLogger("contourcap.router")
    stop = threading.Event()
    stop_on_signals(stop)  # before opening: zenoh.open may block a while after it already listens
    try:
        settings = ZenohSettings(mode="router")
        if args.config:
            cfg = load_config(args.config)
            if cfg.router is None:
                raise ConfigError(f"{cfg.path}: router: no [router] table")
            settings = cfg.router
        if args.zenoh_config:
            settings = replace(settings, config_file=args.zenoh_config)
        if args.listen:
            settings = replace(settings, listen=tuple(args.listen))
        if not settings.listen and not settings.config_file:
            settings = replace(settings, listen=("tcp/0.0.0.0:7447",))
        session = open_session(settings)
    except (ConfigError, BusError, ValueError) as exc:
        print(f"contourcap router: {exc}", file=sys.stderr)
        return 2
    log.info("router %s listening on %s", session.info.zid(), list(settings.listen) or settings.config_file)
    try:
        while not stop.wait(args.stats_s):
            n = sum(1 for _ in session.info.transports())
            log.info("%d connected sessions", n)
    finally:
        session.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    """``python -m service.commands.router``: this command alone (fast start-up)."""
    parser = argparse.ArgumentParser(prog="contourcap router", description=HELP)
    add_args(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    from service.blas import pin_blas_threads

    pin_blas_threads()
    sys.exit(main())
