"""Benchmark: visual hull, initialisation and recovery timings (prints figures; --json for JSON).

    python bench/hull.py [--repeat 5] [--json] [--no-init] [--trials 20]

``--trials N``: N initialisations of T/A poses at random places and headings (joint angles
jittered by 5°) from silhouettes degraded like a real segmentation (a 3x3 dilation or erosion,
blobs and holes), with 6 and 4 cameras: joint-centre error statistics.

Synthetic: 6 ring cameras at 800x600, a random knossow40 pose rendered by ``tracker.imaging.render``.
Real: ``../shared/data/dancer_8view`` (8 x 780x582) when present.
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

from tracker.search.hull import _common_view_bounds, common_view_bounds, visual_hull  # noqa: E402
from tracker.body.kinematics import forward  # noqa: E402
from tracker.body.model import load_model  # noqa: E402
from tracker.imaging.render import render_silhouettes  # noqa: E402
from tracker.synthetic.scene import ring_cameras  # noqa: E402


def _time(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times)), out


def bench_hull(cams, sils, label: str, repeat: int, sizes=(0.03, 0.02, 0.015)) -> list[dict]:
    box = common_view_bounds(cams)
    rows = []
    for s in sizes:
        ms, hull = _time(lambda: visual_hull(cams, sils, min_voxel_m=s, bounds=box), repeat)
        rows.append({"scene": label, "min_voxel_m": s, "hull_ms": round(ms, 1), "voxels": hull.n_voxels,
                     "height_m": round(hull.height(), 3)})
    # uncached: what the per-calibration cache of common_view_bounds saves each hull
    ms, _ = _time(lambda: _common_view_bounds(cams, (0.0, 2.5), 0.2, 0.2), repeat)
    rows.append({"scene": label, "common_view_bounds_uncached_ms": round(ms, 1)})
    return rows


def _degrade(sil: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    import cv2

    k = rng.integers(0, 3)
    kernel = np.ones((3, 3), np.uint8)
    s = cv2.dilate(sil, kernel) if k == 1 else cv2.erode(sil, kernel) if k == 2 else sil.copy()
    for _ in range(3):  # blobs and holes anywhere
        c = (int(rng.integers(0, s.shape[1])), int(rng.integers(0, s.shape[0])))
        cv2.circle(s, c, int(rng.integers(3, 10)), int(rng.choice([0, 255])), -1)
    ys, xs = np.nonzero(s)
    if len(xs):
        i = rng.integers(len(xs))
        cv2.circle(s, (int(xs[i]), int(ys[i])), 8, 0, -1)  # a hole in the body
    return s


def bench_accuracy(model, n_cams: int, trials: int, seed: int = 11) -> dict:
    from tracker.search.initialise import initialise
    from tracker.body.kinematics import joint_centre_array

    cams = ring_cameras(n_cams)
    rng = np.random.default_rng(seed)
    abd = [model.param_index("left_upper_arm.abduction"), model.param_index("right_upper_arm.abduction")]
    errs, times = [], []
    for t in range(trials):
        p = model.zero()
        p[:2], p[5] = rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi)
        p[abd] = np.radians(-45.0) if t % 2 else 0.0
        joints = model.param_kind == 2
        p[joints] += rng.normal(0.0, np.radians(5.0), joints.sum())
        p = model.clamp(p)
        sils = {c.name: _degrade(s, rng) for c, s in zip(cams, render_silhouettes(model, forward(model, p), cams))}
        t0 = time.perf_counter()
        res = initialise(model, cams, sils)
        times.append(time.perf_counter() - t0)
        errs.append(np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                                   - joint_centre_array(model, forward(model, p)), axis=1).mean())
    e = 1e3 * np.array(errs)
    return {"scene": f"initialise accuracy, {n_cams} views, degraded silhouettes", "trials": trials,
            "joint_error_mm_mean": round(float(e.mean()), 1), "median": round(float(np.median(e)), 1),
            "max": round(float(e.max()), 1), "over_30mm": int((e > 30).sum()),
            "ms_median": round(1e3 * float(np.median(times)))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--no-init", action="store_true", help="skip the initialise/recover timings")
    ap.add_argument("--trials", type=int, default=0, help="initialisation accuracy trials per camera count")
    args = ap.parse_args(argv)
    ref_ms = machine_ref_ms()
    model = load_model("knossow40")
    rng = np.random.default_rng(0)
    truth = model.random_params(rng, fraction=0.3)
    cams = ring_cameras(6, size=(800, 600))
    sils = render_silhouettes(model, forward(model, truth), cams)
    rows = bench_hull(cams, sils, "synthetic 6x800x600", args.repeat)
    data = ROOT.parent / "shared" / "data" / "dancer_8view"
    if data.is_dir():
        import cv2

        from capture.calib_formats import read_projection_matrix

        masks = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(data.glob("silh_cam*.pbm"))]
        dcams = [read_projection_matrix(data / "calibration" / f"cam{i:02d}.xml", size=(780, 582)) for i in range(8)]
        rows += bench_hull(dcams, masks, "dancer_8view 8x780x582", args.repeat)
    if not args.no_init:
        from tracker.search.initialise import initialise
        from tracker.body.kinematics import joint_centre_array
        from tracker.search.candidates import turn_about_vertical
        from tracker.search.recovery import recover

        views = {c.name: s for c, s in zip(cams, sils)}
        ref = model.zero()
        ref[:2], ref[5] = [0.4, -0.3], 2.0
        ref_views = {c.name: s for c, s in zip(cams, render_silhouettes(model, forward(model, ref), cams))}
        ms, res = _time(lambda: initialise(model, cams, ref_views), 1)
        err = np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                             - joint_centre_array(model, forward(model, ref)), axis=1).mean()
        rows.append({"scene": "initialise T-pose, 6 views", "ms": round(ms), "candidates": res.candidates,
                     "joint_error_mm": round(1e3 * err, 1)})
        last = turn_about_vertical(model, truth, -np.pi / 2, forward(model, truth).translation[0])
        last[:2] -= [0.4, 0.0]
        ms, res = _time(lambda: recover(model, cams, views, None, last), 1)
        err = np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                             - joint_centre_array(model, forward(model, truth)), axis=1).mean()
        rows.append({"scene": "recover after 90 deg / 40 cm, 6 views", "ms": round(ms), "candidates": res.candidates,
                     "joint_error_mm": round(1e3 * err, 1)})
    if args.trials > 0:
        rows += [bench_accuracy(model, n, args.trials) for n in (6, 4)]
    if args.json:
        print(json.dumps({"machine_ref_ms": ref_ms, "rows": rows}, indent=1))
    else:
        print(f"machine_ref_ms={ref_ms:.2f}")
        for r in rows:
            print("  ".join(f"{k}={v}" for k, v in r.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
