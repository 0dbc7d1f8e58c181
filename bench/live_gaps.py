"""Track losses under live frame gaps, offline and deterministic: the demo clip replayed with gaps.

Live, a fit takes about a frame period, so the tracker fits every first to third frame and its
prediction must bridge uneven gaps where the body accelerates hardest (the hop's take-off and
landing).  A live run is too noisy to compare predictions (its gaps depend on the machine's load);
this replays the demo session (``contourcap demo``'s, segmented once) through a ``Tracker`` set up
as the live fitter sets it (no limb check, no RMS-jump IoU, one of its effort levels), stepping
over the frames by gaps drawn (seeded) from ``--gaps``, twice round the clip.  A loss is a set that
is not ok after an ok one; three sets later the tracker is put back on the ground truth (what a
successful rejoin does), so each loss is counted on its own.  Per ``--velocity-damping`` value
(``TrackerOptions.velocity_damping``) and ``--restart-step`` value (``TrackerOptions.restart_step``;
``none``: off) it prints the losses, the ok share, the mean joint error against the truth, the fit's
CPU per set and the fits from the last pose (``restarts``, of them ``taken``).

    python bench/live_gaps.py [--gaps 1,2,2,3] [--seeds 4] [--effort 0] [--velocity-damping 1,0.5]
                              [--restart-step none,0.1] [--json]
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from machine_ref import machine_ref_ms  # noqa: E402
from segmented_frames import segment_session  # noqa: E402

from capture.session import load_session  # noqa: E402
from service.demo import DemoOptions, demo_session  # noqa: E402
from service.offline import session_model  # noqa: E402
from service.workers.live_fit import EFFORT_LEVELS  # noqa: E402
from tracker.fitting.tracking import Tracker  # noqa: E402

RESET_AFTER = 3
"""Sets after a loss at which the tracker is put back on the truth (a rejoin's stand-in)."""


def segmented(root: Path):
    """(session, truth records, [(frame id, timestamp, {cam: chamfer}, {cam: silhouette})])."""
    session = load_session(root)
    truth = [json.loads(line) for line in (root / "ground_truth.jsonl").read_text().splitlines() if line]
    frames, _ = segment_session(session, len(truth))
    return session, truth, frames


def replay(model, cameras, truth, frames, *, gaps, seed: int, effort: int, damping: float,
           restart_step: float | None = None) -> dict:
    """One replay (module docstring): losses, ok sets, mean joint error (mm), fit CPU per set (ms),
    fits from the last pose and of those the ones kept."""
    rng = np.random.default_rng(seed)
    tr = Tracker(model, cameras, initial_params=np.asarray(truth[0]["params"]), clock=time.process_time)
    tr.recover = False
    level = EFFORT_LEVELS[effort]
    tr.options = replace(tr.options, iou_rms_jump=None, limb_every=0, velocity_damping=damping,
                         restart_step=restart_step, n_samples=level.n_samples, max_iterations=level.max_iterations,
                         reverse_samples=level.reverse_samples)
    order = list(range(len(frames))) * 2
    pos, sets, ok_sets, cpu, errors, losses, reset_at, last_ok = 0, 0, 0, 0.0, [], [], None, True
    while pos < len(order):
        k = order[pos]
        _, ts, chamfer, sils = frames[k]
        if reset_at is not None and pos >= reset_at:
            tr.params, tr.previous = np.asarray(truth[k]["params"], float), None
            tr.monitor.reset()
            reset_at, last_ok = None, True
        c0 = time.process_time()
        rec = tr.step(pos, ts, chamfer, silhouettes=sils)  # live frame ids: increasing through the loops
        cpu += time.process_time() - c0
        sets += 1
        ok = bool(rec.get("ok"))
        ok_sets += ok
        if rec.get("joints"):
            tj = truth[k]["joints"]
            errors.append(np.mean([np.linalg.norm(np.subtract(rec["joints"][j], tj[j]))
                                   for j in tj if j in rec["joints"]]))
        if last_ok and not ok and reset_at is None:
            losses.append(k)
            reset_at = pos + RESET_AFTER
        last_ok = ok
        pos += int(rng.choice(gaps))
    return {"sets": sets, "ok": ok_sets, "losses": len(losses), "loss_frames": losses,
            "mean_joint_error_mm": 1e3 * float(np.mean(errors)), "fit_cpu_ms_per_set": 1e3 * cpu / sets,
            "restarts": tr.n_restarts, "restarts_taken": tr.n_restarts_taken}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--session", type=Path, default=None,
                    help="a session with ground_truth.jsonl (default: the demo's)")
    ap.add_argument("--gaps", default="1,2,2,3", help="frame gaps drawn between fits")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--effort", type=int, default=0, choices=range(len(EFFORT_LEVELS)))
    ap.add_argument("--velocity-damping", default="1,0.5", help="values compared")
    ap.add_argument("--restart-step", default="none", help="TrackerOptions.restart_step values compared (none: off)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    cv2.setNumThreads(1)
    ref = machine_ref_ms()
    root = args.session or demo_session(DemoOptions(), progress=lambda s: print(s, file=sys.stderr))
    session, truth, frames = segmented(root)
    model, cameras = session_model(session, "knossow40"), list(session.calibration)
    gaps = [int(g) for g in args.gaps.split(",")]
    restarts = [None if v.strip().lower() == "none" else float(v) for v in args.restart_step.split(",")]
    result = {"machine_ref_ms": ref, "session": str(root), "gaps": gaps, "seeds": args.seeds, "effort": args.effort,
              "reset_after_sets": RESET_AFTER, "damping": {}}
    for d, step in ((float(v), r) for v in args.velocity_damping.split(",") for r in restarts):
        runs = [replay(model, cameras, truth, frames, gaps=gaps, seed=s, effort=args.effort, damping=d,
                       restart_step=step) for s in range(args.seeds)]
        tot = {k: sum(r[k] for r in runs) for k in ("sets", "ok", "losses", "restarts", "restarts_taken")}
        tot["ok_percent"] = 100.0 * tot["ok"] / tot["sets"]
        tot["mean_joint_error_mm"] = float(np.mean([r["mean_joint_error_mm"] for r in runs]))
        tot["fit_cpu_ms_per_set"] = float(np.mean([r["fit_cpu_ms_per_set"] for r in runs]))
        tot["fit_cpu_per_set_over_machine_ref"] = tot["fit_cpu_ms_per_set"] / ref
        tot["loss_frames"] = [r["loss_frames"] for r in runs]
        key = f"{d:g}" if restarts == [None] else f"{d:g} restart {'none' if step is None else f'{step:g}'}"
        result["damping"][key] = tot
        if not args.json:
            print(f"damping {key}: losses {tot['losses']:3d}  ok {tot['ok_percent']:5.1f} %  "
                  f"error {tot['mean_joint_error_mm']:5.1f} mm  fit CPU {tot['fit_cpu_ms_per_set']:5.1f} ms/set  "
                  f"restarts {tot['restarts']} ({tot['restarts_taken']} taken)")
    if args.json:
        print(json.dumps(result))
    else:
        print(f"machine_ref_ms {ref:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
