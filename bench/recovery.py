"""Benchmark: loss recovery time and success (prints figures; --json for JSON).

    python bench/recovery.py [--json] [--cameras 6 4] [--size 640 480] [--gaps 5 8 10] [--every 10]

Scenarios (``tracker.search.recovery.recover`` called as the Tracker calls it: the last good pose, the
frame's silhouettes and chamfer images):

* ``hop drop``: the bundled CMU hop (``scaled_131_03``, 120 frames) rendered by
  ``tracker.imaging.render`` (silhouettes and internal edges); the last good pose is the truth at frame k,
  the frame to recover is k + gap (``--gaps`` frames dropped), k every ``--every`` frames;
* ``turn 90``: as in tests/test_recovery.py (a random pose; since the last good frame the
  subject turned 90° and walked 40 cm), silhouette-only chamfer images, 6 × 800×600, 5 seeds;
* ``mirrored``: the hop's first frame, the last good pose its front/back mirror (4 × 320×240).

Per scenario: recovery time (CPU time of this single-threaded process — what one idle core
would take, robust to other load on the machine — median, p90, max; and the wall-clock median),
mean joint-centre error (median, max)
and the share of recoveries within ``--ok-mm`` (default 30 mm) of the truth, also after the
Tracker's own fit from the recovered pose (``tracker.fitting.tracking.fit_frame``, what the frame reports).  ``--init``: also
time the automatic initialisation of the hop's first frame.  ``--tracker``: the Tracker itself through
``--gaps`` dropped frames at each of ``--drops`` (its searches' latency, frames not ok, errors).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from machine_ref import machine_ref_ms  # noqa: E402

from tracker.search.scoring import rendered_views  # noqa: E402
from tracker.body.kinematics import forward, joint_centre_array  # noqa: E402
from tracker.synthetic.scene import ring_cameras  # noqa: E402


def joint_error_m(model, a, b) -> float:
    return float(np.linalg.norm(joint_centre_array(model, forward(model, a))
                                - joint_centre_array(model, forward(model, b)), axis=1).mean())


def run_case(model, cams, sils, chamfer, last, truth) -> dict:
    from tracker.search.recovery import recover
    from tracker.fitting.tracking import fit_frame

    t0, c0 = time.perf_counter(), time.process_time()
    res = recover(model, cams, sils, chamfer, last)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    fit, _ = fit_frame(model, cams, chamfer, np.asarray(res.params))  # the Tracker's fit next
    return {"s": dt, "cpu_s": cpu, "err_m": joint_error_m(model, res.params, truth), "label": res.label,
            "iou": res.score, "fit_err_m": joint_error_m(model, fit.params, truth)}


def summary(name: str, rows: list[dict], ok_mm: float) -> dict:
    t, c = np.array([r["s"] for r in rows]), np.array([r["cpu_s"] for r in rows])
    e, f = 1e3 * np.array([r["err_m"] for r in rows]), 1e3 * np.array([r["fit_err_m"] for r in rows])
    labels: dict[str, int] = {}
    for r in rows:
        labels[r["label"]] = labels.get(r["label"], 0) + 1
    return {"scenario": name, "cases": len(rows), "cpu_ms_median": round(1e3 * float(np.median(c))),
            "cpu_ms_p90": round(1e3 * float(np.percentile(c, 90))), "cpu_ms_max": round(1e3 * float(c.max())),
            "wall_ms_median": round(1e3 * float(np.median(t))),
            "err_mm_median": round(float(np.median(e)), 1), "err_mm_max": round(float(e.max()), 1),
            f"within_{ok_mm:g}mm": f"{int((e < ok_mm).sum())}/{len(e)}",
            "after_fit_err_mm_median": round(float(np.median(f)), 1), "after_fit_err_mm_max": round(float(f.max()), 1),
            f"after_fit_within_{ok_mm:g}mm": f"{int((f < ok_mm).sum())}/{len(f)}", "labels": labels}


def hop_motion(frames: int = 120):
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.retarget import retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    return retarget_bvh(load_bvh(bundled_motion("scaled_131_03")), frames=frames, start_s=0.0)


def bench_hop_drop(n_cams: int, size, gaps, every: int, ok_mm: float, mot) -> dict:
    model, P = mot.model, mot.params
    cams = ring_cameras(n_cams, size=tuple(size), start_deg=20.0)
    rows = []
    for gap in gaps:
        for k in range(0, len(P) - gap, every):
            sils, chamfer = rendered_views(model, P[k + gap], cams)
            rows.append(run_case(model, cams, sils, chamfer, P[k], P[k + gap]) | {"k": k, "gap": gap})
    out = summary(f"hop drop {list(gaps)} frames, {n_cams} x {size[0]}x{size[1]}", rows, ok_mm)
    out["worst"] = [(r["k"], r["gap"], round(1e3 * r["err_m"])) for r in sorted(rows, key=lambda r: -r["err_m"])[:3]]
    return out


def bench_turn(ok_mm: float, seeds=(21, 22, 23, 24, 25)) -> dict:
    from tracker.search.scoring import chamfer_from_silhouette
    from tracker.body.model import load_model
    from tracker.search.candidates import turn_about_vertical
    from tracker.imaging.render import render_silhouettes

    model = load_model("knossow40")
    cams = ring_cameras(6)
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        last = model.random_params(rng, fraction=0.3)
        last[:2] = [-0.2, 0.1]
        walked = turn_about_vertical(model, last, np.pi / 2, forward(model, last).translation[0])
        walked[0] += 0.4  # turned 90°, walked 40 cm, the limbs moved by ~4°
        jitter = np.where(model.param_kind == 2, rng.normal(0.0, np.radians(4.0), model.n_params), 0.0)
        truth = model.clamp(walked + jitter)
        sils = {c.name: s for c, s in zip(cams, render_silhouettes(model, forward(model, truth), cams))}
        chamfer = {n: chamfer_from_silhouette(s) for n, s in sils.items()}
        rows.append(run_case(model, cams, sils, chamfer, last, truth))
    return summary("turn 90 deg / 40 cm, 6 x 800x600", rows, ok_mm)


def bench_mirrored(ok_mm: float, mot) -> dict:
    from tracker.search.mirror import mirror_params

    model = mot.model
    cams = ring_cameras(4, size=(320, 240), start_deg=20.0)
    rows = []
    for k in (0, 30, 60):
        truth = mot.params[k]
        sils, chamfer = rendered_views(model, truth, cams)
        rows.append(run_case(model, cams, sils, chamfer, mirror_params(model, truth), truth))
    return summary("mirrored last pose (hop frames 0/30/60), 4 x 320x240", rows, ok_mm)


def bench_tracker(n_cams: int, size, gap: int, drops, ok_mm: float, mot, after: int = 12) -> dict:
    """The Tracker (``tracker.fitting.tracking.Tracker``, CPU-time clock) on the hop from the true first
    pose; at each frame of ``drops`` the next ``gap`` frames are dropped, and it tracks on for
    ``after`` frames: its searches (recoveries) and their latency, the frames reported not ok,
    and the mean joint error over the frames after the drop."""
    from tracker.fitting.tracking import Tracker

    model, P = mot.model, mot.params
    cams = ring_cameras(n_cams, size=tuple(size), start_deg=20.0)
    lat, bad, errs, searches = [], 0, [], 0
    for k in drops:
        tracker = Tracker(model, cams, initial_params=P[max(k - 3, 0)], clock=time.process_time)
        for f in list(range(max(k - 3, 0), k + 1)) + list(range(k + 1 + gap, min(k + 1 + gap + after, len(P)))):
            sils, chamfer = rendered_views(model, P[f], cams)
            n0 = tracker.n_initialisations
            rec = tracker.step(f, 0, chamfer, sils)
            if f > k:
                bad += not rec["ok"]
                errs.append(joint_error_m(model, np.asarray(rec["params"]), P[f]) if "params" in rec else np.nan)
            if tracker.n_initialisations > n0:
                lat.append(rec["latency_ms"])
                searches += 1
    e = 1e3 * np.array(errs)
    return {"scenario": f"Tracker, hop, {gap} frames dropped at {list(drops)}, {n_cams} x {size[0]}x{size[1]}",
            "searches": searches, "search_frame_cpu_ms_median": round(float(np.median(lat))) if lat else None,
            "search_frame_cpu_ms_max": round(float(np.max(lat))) if lat else None,
            "frames_not_ok": f"{bad}/{len(e)}", "err_mm_mean_after_drop": round(float(np.nanmean(e)), 1),
            f"frames_within_{ok_mm:g}mm": f"{int((e < ok_mm).sum())}/{len(e)}"}


def bench_init(n_cams: int, size, mot) -> dict:
    from tracker.search.initialise import initialise

    cams = ring_cameras(n_cams, size=tuple(size), start_deg=20.0)
    sils, chamfer = rendered_views(mot.model, mot.params[0], cams)
    t0, c0 = time.perf_counter(), time.process_time()
    res = initialise(mot.model, cams, sils, chamfer)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"scenario": f"initialise hop frame 0, {n_cams} x {size[0]}x{size[1]}", "cpu_ms": round(1e3 * cpu),
            "wall_ms": round(1e3 * dt),
            "err_mm": round(1e3 * joint_error_m(mot.model, res.params, mot.params[0]), 1), "label": res.label}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--cameras", type=int, nargs="+", default=[6, 4])
    ap.add_argument("--size", type=int, nargs=2, default=[640, 480])
    ap.add_argument("--gaps", type=int, nargs="+", default=[5, 8, 10])
    ap.add_argument("--every", type=int, default=10)
    ap.add_argument("--ok-mm", type=float, default=30.0)
    ap.add_argument("--skip", nargs="*", default=[], choices=["hop", "turn", "mirrored"])
    ap.add_argument("--init", action="store_true", help="also time the initialisation of the hop's first frame")
    ap.add_argument("--tracker", action="store_true", help="also run the Tracker through dropped frames")
    ap.add_argument("--drops", type=int, nargs="+", default=[20, 50, 80])
    args = ap.parse_args(argv)
    ref_ms = machine_ref_ms()
    mot = hop_motion()
    rows = []
    if "hop" not in args.skip:
        rows += [bench_hop_drop(n, args.size, args.gaps, args.every, args.ok_mm, mot) for n in args.cameras]
    if "turn" not in args.skip:
        rows.append(bench_turn(args.ok_mm))
    if "mirrored" not in args.skip:
        rows.append(bench_mirrored(args.ok_mm, mot))
    if args.init:
        rows += [bench_init(n, args.size, mot) for n in args.cameras]
    if args.tracker:
        rows += [bench_tracker(n, args.size, gap, args.drops, args.ok_mm, mot)
                 for n in args.cameras for gap in args.gaps]
    lines = ("  ".join(f"{k}={v}" for k, v in r.items()) for r in rows)
    print(json.dumps({"machine_ref_ms": ref_ms, "rows": rows}, indent=1) if args.json
          else "\n".join([f"machine_ref_ms={ref_ms:.2f}", *lines]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
