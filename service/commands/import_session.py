"""``contourcap import FORMAT SRC OUT``: convert a recording from elsewhere into a session directory.

    contourcap import uu_studio ../shared/data/uu_studio sessions/uu_studio

Formats: ``uu_studio`` (see ``capture.uu_studio``): calibrates the cameras
from the floor checkerboard and links (``--copy``: copies) the videos.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

HELP = "import a recording from another layout (uu_studio) as a contourcap session directory"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("format", choices=["uu_studio"], help="layout of the source recording")
    parser.add_argument("src", type=Path, help="source folder")
    parser.add_argument("out", type=Path, help="session directory to create")
    parser.add_argument("--copy", action="store_true", help="copy the videos instead of symlinking them")
    parser.add_argument("--corners-file", type=Path, default=None,
                        help="board outlines / origin hints (default: the ones shipped for uu_studio)")
    parser.add_argument("--name", default="uu_studio", help="session name (default uu_studio)")
    parser.add_argument("--force", action="store_true", help="replace a session already in OUT")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from capture.uu_studio import CORNERS_FILE, UUImportError, import_uu_studio
    from service.progress import Progress

    bar = Progress(unit="steps", enabled=not args.quiet)
    try:
        res = import_uu_studio(args.src, args.out, corners_file=args.corners_file or CORNERS_FILE, copy=args.copy,
                               name=args.name, overwrite=args.force, progress=bar)
    except (UUImportError, ValueError, OSError) as exc:
        bar.close()
        print(f"contourcap import: error: {exc}", file=sys.stderr)
        return 2
    bar.close()
    for r in res.calibration.extrinsics.reports:
        print(f"{r.name}: {r.method} corners, frames {list(r.frames)}, RMS {r.rms_px:.3f} px, "
              f"{res.frame_counts[r.name]} frames of video")
    print(f"wrote session {res.session_dir} ({len(res.cameras)} cameras, {res.fps:g} fps)")
    return 0
