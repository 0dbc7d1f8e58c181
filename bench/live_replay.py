"""Benchmark: the live fitter on the demo clip offline, under frame gaps and slow searches.

``service.live_replay.replay_live`` fits the frame ids a live tracker would get (``--gaps``:
every n-th frame, a list is cycled, e.g. ``2,1,3``) of the looped demo clip (``contourcap demo``'s
session, rendered once into ``--cache-dir``), segmented in the live fitter's regions of interest,
its searches held back for as many sets as they would take live (``--search-sets
default=15,rejoin=3``, or ``--sets-per-cpu-s 60``: a search's CPU seconds × that, i.e. the frame
rate times how much slower a search runs beside the stream than alone).  Prints ok sets, mean
joint error over ok sets and over all sets with a pose, searches by kind, and the bad sets' clip
frames.  ``--catch-up N`` sets how many sets a search's pose is brought forward through
(``LiveTrackerFitter.catch_up_sets``; 0: none), ``--start`` the first frame id, ``--rejoin-headings`` the cheap rejoin's headings per seed.  The fitter's clock is the thread's CPU time, so
``rejoin_cpu_ms`` lists the CPU of each rejoin run in a set's time (``rejoin_ok``: how many of those
sets ended ok).  ``--old-recovery`` turns off the cheap rejoin at once (``rejoin_spacing`` -1) for A/B
runs on one tree; ``--restart-step`` sets ``LiveTrackerFitter(restart_step=)`` (``none``: off; the fits from the
last pose are counted in ``restarts`` / ``restarts_taken``).

    python bench/live_replay.py [--json] [--sets 180] [--gaps 1 2 3 2,1,3] [--search-sets default=15,rejoin=3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # before bench/ (its tracker.py would shadow the package)
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import numpy as np  # noqa: E402

from machine_ref import machine_ref_ms  # noqa: E402


def parse_sets(text: str) -> dict:
    """``"default=15,rejoin=3"`` (or a bare ``"15"`` for the default) -> {kind: sets}."""
    out = {}
    for item in text.split(","):
        key, eq, value = item.partition("=")
        if not eq:
            key, value = "default", key
        try:
            out[key.strip() or "default"] = int(value)
        except ValueError:
            raise SystemExit(f"live_replay.py: --search-sets {text!r}: expected KIND=SETS[,KIND=SETS] or SETS") from None
    return out


def main() -> None:
    from service.demo import DemoOptions, demo_session
    from service.live_replay import HeldSearches, clip_joint_errors, every_nth, load_clip, replay_live
    from service.workers.live_fit import LiveTrackerFitter

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--session", type=Path, help="a session folder (default: the demo's)")
    ap.add_argument("--cache-dir", type=Path, default=DemoOptions().cache_dir)
    ap.add_argument("--sets", type=int, default=180)
    ap.add_argument("--gaps", nargs="+", default=["1", "2", "3", "2,1,3"])
    ap.add_argument("--search-sets", default="default=15,rejoin=3")
    ap.add_argument("--sets-per-cpu-s", type=float, default=None)
    ap.add_argument("--no-rois", action="store_true")
    ap.add_argument("--old-recovery", action="store_true")
    ap.add_argument("--catch-up", type=int, default=None, help="LiveTrackerFitter catch_up_sets (default: its own)")
    ap.add_argument("--start", type=int, default=0, help="first frame id of the schedules")
    ap.add_argument("--rejoin-headings", type=int, default=None,
                    help="LiveTrackerFitter rejoin_headings (default: its own)")
    ap.add_argument("--restart-step", default=None,
                    help="LiveTrackerFitter restart_step, a fraction of height or 'none' (default: its own)")
    args = ap.parse_args()
    ref = machine_ref_ms()
    root = args.session or demo_session(DemoOptions(cache_dir=args.cache_dir), progress=lambda m: None)
    clip = load_clip(root)
    runs = []
    for gaps in args.gaps:
        gap = [int(g) for g in gaps.split(",")]
        runner = HeldSearches(parse_sets(args.search_sets), sets_per_cpu_s=args.sets_per_cpu_s)
        extra = dict(rejoin_spacing=-1) if args.old_recovery else {}
        if args.catch_up is not None:
            extra["catch_up_sets"] = args.catch_up
        if args.rejoin_headings is not None:
            extra["rejoin_headings"] = args.rejoin_headings
        if args.restart_step is not None:
            extra["restart_step"] = None if args.restart_step.lower() == "none" else float(args.restart_step)
        # the fitter's clock is the thread's CPU: a record's fit_ms / rejoin_ms are CPU, not wall
        fitter = LiveTrackerFitter.from_session(clip.session, search_runner=runner, clock=time.thread_time, **extra)
        c0 = time.process_time()
        rep = replay_live(clip, every_nth(args.sets, gap, start=args.start), fitter=fitter, use_rois=not args.no_rois)
        cpu = time.process_time() - c0
        err = clip_joint_errors(clip, rep.records)
        ok = np.array([bool(r.get("ok")) for r in rep.records])
        run = {"gaps": gap, "sets": len(rep.records), "ok": int(ok.sum()),
               "mean_joint_error_ok_m": float(np.nanmean(err[ok])) if ok.any() else None,
               "mean_joint_error_all_m": float(np.nanmean(err)) if np.isfinite(err).any() else None,
               "searches": dict(getattr(fitter, "search_kinds", {"all": fitter.searches})), "rejoined": fitter.rejoined,
               "held_sets": [s for _, s in runner.held],
               "rejoin_cpu_ms": [round(r["rejoin_ms"], 1) for r in rep.records if "rejoin_ms" in r],
               "rejoin_ok": sum(bool(r.get("ok")) for r in rep.records if "rejoin_ms" in r),
               "restarts": fitter.tracker.n_restarts, "restarts_taken": fitter.tracker.n_restarts_taken,
               "roi_sets": rep.roi_sets, "cpu_ms_per_set": 1e3 * cpu / max(1, len(rep.records)),
               "bad_clip_frames": [int(r["frame"]) % clip.n_frames for r in rep.records if not r.get("ok")]}
        runs.append(run)
        if not args.json:
            e_ok, e_all = run["mean_joint_error_ok_m"], run["mean_joint_error_all_m"]
            print(f"gaps {gaps:>6}: ok {run['ok']}/{run['sets']}, error ok {100 * (e_ok or np.nan):.2f} cm, "
                  f"all {100 * (e_all or np.nan):.2f} cm, searches {run['searches']}, rejoined {run['rejoined']}, "
                  f"{run['cpu_ms_per_set']:.1f} ms CPU per set; rejoins in the set's time {len(run['rejoin_cpu_ms'])} "
                  f"({run['rejoin_ok']} ok, {sum(run['rejoin_cpu_ms']):.0f} ms CPU); bad clip frames {run['bad_clip_frames']}", flush=True)
    out = {"machine_ref_ms": ref, "search_sets": args.search_sets, "sets_per_cpu_s": args.sets_per_cpu_s,
           "old_recovery": args.old_recovery, "catch_up": args.catch_up, "start": args.start,
           "rejoin_headings": args.rejoin_headings, "restart_step": args.restart_step, "rois": not args.no_rois,
           "runs": runs}
    if args.json:
        print(json.dumps(out, indent=1))
    else:
        print(f"machine_ref_ms {ref:.1f}")


if __name__ == "__main__":
    main()
