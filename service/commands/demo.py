"""``contourcap demo``: render a synthetic studio from bundled CMU motion and run the live pipeline on it."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from service.commands.argtypes import positive_float
from service.commands.synth import image_size

HELP = "run the whole live pipeline over zenoh on loopback on a synthetic studio (rendered once, cached)"


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cameras", type=int, default=6, help="cameras on a ring around the subject (default 6)")
    parser.add_argument("--frames", type=int, default=90,
                        help="frames of motion at --fps (default 90: a 3 s hop); the clip plays them forward then "
                             "backward (2N-2 frames) unless --no-bounce")
    parser.add_argument("--no-bounce", action="store_true",
                        help="the clip plays the motion forward only: a looped live replay then jumps from the last "
                             "pose to the first once per pass (a recovery test)")
    parser.add_argument("--decode-live", action="store_true",
                        help="live: the replay cameras decode the session's videos while streaming (default: they "
                             "hold the clip decoded in memory when it takes at most 1 GB, as a camera delivers "
                             "decoded frames)")
    parser.add_argument("--size", type=image_size, default=(320, 240), help="WIDTHxHEIGHT of the cameras")
    parser.add_argument("--fps", type=positive_float, default=30.0)
    parser.add_argument("--motion", default="scaled_131_03", help="bundled CMU clip (tracker/data)")
    parser.add_argument("--live", action="store_true",
                        help="live delivery (real-time replay, stale sets dropped) instead of lossless")
    parser.add_argument("--out", default=None,
                        help="folder for poses.jsonl, poses.bvh, demo.rrd (default: <cache>/last-demo)")
    parser.add_argument("--cache", default=None, help="where the rendered session is kept (~/.cache/contourcap)")
    parser.add_argument("--timeout-s", type=float, default=1800.0)
    parser.add_argument("--duration-s", type=float, default=20.0, help="live: how long the looped replay runs")
    parser.add_argument("--image-cameras", type=int, default=0,
                        help="live: how many cameras' images and silhouettes the viewer (demo.rrd) takes (default "
                             "0: poses only; a tapped camera's every frame reaches the demo process, which competes "
                             "with the pipeline)")
    parser.add_argument("--segment-plugin", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--fit-plugin", default=None, help=argparse.SUPPRESS)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")


def options_from_args(args: argparse.Namespace):
    from service.demo import DemoOptions

    kw = dict(cameras=args.cameras, frames=args.frames, size=tuple(args.size), fps=args.fps, motion=args.motion,
              delivery="live" if args.live else "lossless", out_dir=None if args.out is None else Path(args.out),
              timeout_s=args.timeout_s,
              segment_plugin=args.segment_plugin, fit_plugin=args.fit_plugin,
              live_duration_s=args.duration_s, live_image_cameras=args.image_cameras,
              bounce=not args.no_bounce)
    if args.decode_live:
        kw["live_preload_mb"] = 0.0
    if args.cache:
        kw["cache_dir"] = Path(args.cache)
    return DemoOptions(**kw)


def run(args: argparse.Namespace) -> int:
    from service.demo import run_demo

    if args.cameras < 1 or args.frames < 2:
        print("contourcap demo: --cameras >= 1 and --frames >= 2", file=sys.stderr)
        return 2
    from tracker.synthetic.synth import bundled_motion

    bundled_motion(args.motion)  # an unknown motion is refused before anything is rendered or started
    say = (lambda msg: print(msg, file=sys.stderr, flush=True))
    summary = run_demo(options_from_args(args), progress=say)
    if args.json:
        print(json.dumps(summary.as_dict()))
        return 0

    def f(v, fmt):
        return "n/a" if v is None else format(v, fmt)

    print(f"frames {summary.frames} ({summary.ok} ok) from {summary.cameras} cameras in {summary.wall_s:.1f} s\n"
          f"fps out {summary.fps_out:.2f} (in {summary.fps_in:.1f}, realtime x{summary.realtime_factor:.2f}; "
          f"first to last pose)\n"
          + (f"poses/s {summary.poses_per_s:.2f} over the replay window\n" if summary.poses_per_s is not None else "")
          + f"latency p50 {f(summary.latency_ms_p50, '.1f')} ms, p99 {f(summary.latency_ms_p99, '.1f')} ms\n"
          f"median rms {f(summary.median_rms_px, '.2f')} px, mean joint error "
          f"{f(None if summary.mean_joint_error_m is None else 100 * summary.mean_joint_error_m, '.1f')} cm\n"
          f"dropped sets {summary.dropped_sets}"
          + (f", demand timeouts {summary.demand_timeouts}" if summary.demand_timeouts is not None else "")
          + (f", missing cameras {summary.missing_cameras}" if summary.missing_cameras is not None else "")
          + f", cpu {summary.cpu_percent:.0f} %\n"
          f"poses {summary.poses}\nbvh   {summary.bvh or 'n/a'}\nrrd   {summary.rrd}")
    return 0
