"""The ``contourcap`` command line: a thin dispatcher.

Each sub-command lives in ``service/commands/<name>.py`` and exposes
``HELP`` (one line), ``add_args(parser)`` and ``run(args) -> int``.  The
work itself is done by library functions that never see argparse.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

# name -> module under service.commands (module names avoid Python keywords)
COMMANDS = {
    "demo": "demo",
    "synth": "synth",
    "track": "track",
    "segment": "segment",
    "calibrate": "calibrate",
    "import": "import_session",
    "record": "record",
    "replay": "replay",
    "run": "run",
    "worker": "worker",
    "router": "router",
    "echo": "echo",
    "view": "view",
    "export": "export",
}


def _available() -> dict[str, str]:
    out = {}
    for name, mod in COMMANDS.items():
        if importlib.util.find_spec(f"service.commands.{mod}") is not None:
            out[name] = mod
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="contourcap",
        description="Live markerless multi-camera motion capture (extremal-contour tracking over zenoh).",
    )
    parser.add_argument("--version", action="version", version=f"contourcap {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in _available().items():
        module = importlib.import_module(f"service.commands.{mod}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_args(p)
        p.set_defaults(_run=module.run)
    return parser


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("contourcap")
    except Exception:  # not installed (running from a checkout)
        return "0+unknown"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
