"""``contourcap synth BVH OUT``: render a synthetic multi-camera session with ground truth."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from service.commands.argtypes import positive_float

HELP = "render a synthetic session (videos, calibration, ground truth) from BVH motion"


def image_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must be WIDTHxHEIGHT (e.g. 800x600), got {text!r}") from None
    if w < 16 or h < 16 or w > 8192 or h > 8192:
        raise argparse.ArgumentTypeError(f"--size must be between 16x16 and 8192x8192, got {text!r}")
    return w, h


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bvh", help="BVH motion file, or 'bundled:NAME' (scaled_131_01, scaled_131_03)")
    parser.add_argument("out", help="session directory to write")
    parser.add_argument("--cameras", type=int, default=6, help="number of ring cameras (default 6)")
    parser.add_argument("--size", type=image_size, default=(800, 600), help="image size WIDTHxHEIGHT (default 800x600)")
    parser.add_argument("--frames", type=int, default=None, help="number of frames (default: the whole clip)")
    parser.add_argument("--start", type=float, default=0.0, help="start time in the BVH clip, seconds")
    parser.add_argument("--fps", type=positive_float, default=30.0, help="output frame rate (default 30)")
    parser.add_argument("--model", default="knossow40", help="body model (default knossow40)")
    parser.add_argument("--noise", type=float, default=2.0, help="Gaussian pixel noise sigma, grey levels (default 2)")
    parser.add_argument("--shadow", action=argparse.BooleanOptionalAction, default=True, help="cast shadow on the floor")
    parser.add_argument("--codec", choices=("ffv1", "png", "mjpg"), default="ffv1", help="video codec (default ffv1, lossless)")
    parser.add_argument("--masks", action="store_true", help="also write true silhouettes masks/camN/%%06d.png")
    parser.add_argument("--fit-segments", action="store_true",
                        help="give the model the BVH's limb lengths (written to session.toml)")
    parser.add_argument("--background-frames", type=int, default=50, help="frames of empty-room video (default 50)")
    parser.add_argument("--seed", type=int, default=0, help="seed of textures, colours, light and noise")
    parser.add_argument("--force", action="store_true", help="write into OUT even if it is not empty")


def run(args: argparse.Namespace) -> int:
    from tracker.synthetic.bvh import BvhError
    from tracker.body.model import ModelError
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.synth import bundled_motion

    from service.progress import Progress

    progress = Progress(enabled=not getattr(args, "quiet", False))

    try:
        out = Path(args.out)
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
            raise ValueError(f"{out}: exists and is not an empty folder (a session is never overwritten "
                             f"without --force)")
        bvh = bundled_motion(args.bvh.split(":", 1)[1]) if args.bvh.startswith("bundled:") else args.bvh
        out = make_synthetic_session(
            bvh, args.out, cameras=args.cameras, size=args.size, frames=args.frames, fps=args.fps,
            start_s=args.start, noise=args.noise, shadow=args.shadow, model=args.model, seed=args.seed,
            codec=args.codec, masks=args.masks, n_background=args.background_frames,
            fit_segments=args.fit_segments, progress=progress,
        )  # fmt: skip
    except (BvhError, ModelError, ValueError, FileNotFoundError, OSError, RuntimeError) as exc:
        progress.close()
        print(f"contourcap synth: {exc}", file=sys.stderr)
        return 2
    progress.close()
    print(f"wrote {out}")
    return 0
