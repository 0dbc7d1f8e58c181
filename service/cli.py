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
import traceback

from service.blas import pin_blas_threads

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
    "stream": "stream",
    "review": "review",
}


def _command_in(argv: list[str]) -> str | None:
    """The sub-command named in ``argv`` (the first non-option word), if it is one of ours."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else None
    return None


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The CLI parser.  With ``command``, only that sub-command's module is imported (a broken or slow
    module never affects another command); without, every module is imported for the help listing."""
    parser = argparse.ArgumentParser(
        prog="contourcap",
        description="Live markerless multi-camera motion capture (extremal-contour tracking over zenoh).",
    )
    parser.add_argument("--version", action="version", version=f"contourcap {_version()}")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error (anywhere on the line)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, mod in COMMANDS.items():
        if command is not None and name != command:
            sub.add_parser(name)
            continue
        try:
            module = importlib.import_module(f"service.commands.{mod}")
        except ImportError as exc:
            if command is not None:
                raise
            sub.add_parser(name, help=f"(unavailable: {exc})")
            continue
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
    pin_blas_threads()  # before any command imports numpy
    argv = sys.argv[1:] if argv is None else list(argv)
    debug = "--debug" in argv  # anywhere on the line: it is the CLI's, not a sub-command's
    argv = [a for a in argv if a != "--debug"]
    parser = build_parser(_command_in(argv))
    args = parser.parse_args(argv)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `contourcap ... | head`
        return 0
    except user_errors() as exc:
        if debug:
            traceback.print_exc()
        print(f"contourcap {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug: one line, the traceback on request
        if debug:
            traceback.print_exc()
        print(f"contourcap {args.command}: unexpected {exc.__class__.__name__}: {one_line(exc)} "
              "(a bug: please report it with the output of --debug)", file=sys.stderr)
        return 1


def user_errors() -> tuple[type[BaseException], ...]:
    """The error types that mean bad input (one line, exit 2): each package's base, and OSError."""
    from capture.errors import CaptureError
    from segmentation.errors import SegmentationError
    from service.errors import ServiceError
    from tracker.errors import TrackerError

    return (CaptureError, SegmentationError, TrackerError, ServiceError, OSError, UnicodeError)


def one_line(exc: BaseException) -> str:
    """``exc`` as one printable line: an OSError names its file, control characters are escaped."""
    from service.text import printable

    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or exc.__class__.__name__
    return printable(" ".join(text.split()), limit=2000)


if __name__ == "__main__":
    sys.exit(main())
