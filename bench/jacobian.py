"""Benchmark: extremal contours + their Jacobian for one frame (6 ring cameras, 800x600).

Prints the median time per frame over random poses of

- ``extremal_contours`` (n_samples=20 per ruling, i.e. 40 points per part, with visibility),
- ``contour_jacobian`` on the visible points (what a solver iteration needs),
- ``tracker.imaging.render.render_silhouettes`` for the 6 cameras (null if the module is absent),

and the largest per-point relative error of the analytic Jacobian against central
finite differences (all valid points, the first ``--fd-poses`` poses).  Each pose is
timed as the best of ``--repeat`` runs, then the median over poses; ``ms_*`` are
wall-clock, ``cpu_ms_*`` process CPU time (single-threaded work: equal to wall-clock
on an idle machine, and still meaningful on a shared, overloaded one).

BLAS threads: the matrix products here are small, where OpenBLAS threading only adds
wake-up latency (and, on a loaded machine, stalls of milliseconds), so this script
sets ``OPENBLAS_NUM_THREADS=1`` unless the environment already sets it; the tracker
process should do the same.

    python bench/jacobian.py [--model knossow40] [--poses 30] [--json]
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402

from tracker.imaging.contours import extremal_contours  # noqa: E402
from tracker.imaging.jacobian import contour_jacobian  # noqa: E402
from tracker.body.kinematics import forward  # noqa: E402
from tracker.body.model import load_model  # noqa: E402
from tracker.synthetic.scene import ring_cameras  # noqa: E402

try:
    from tracker.imaging.render import render_silhouettes
except ImportError:  # pragma: no cover - the renderer is optional here
    render_silhouettes = None

N_SAMPLES = 20


def best_ms(fn, repeat: int) -> tuple[float, float]:
    """Best wall-clock and best CPU (process) time of ``repeat`` runs, milliseconds."""
    wall = cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return wall * 1e3, cpu * 1e3


def fd_error(model, params, cameras, contours, h=1e-6) -> float:
    """max over valid points of ||J - FD|| / ||FD|| (whole 2 x n_params block per point)."""
    pose = forward(model, params)
    J = contour_jacobian(model, pose, cameras, contours)
    fd = np.empty_like(J)
    for k in range(model.n_params):
        dp = np.zeros(model.n_params)
        dp[k] = h
        plus = extremal_contours(model, forward(model, params + dp), cameras, n_samples=N_SAMPLES, visibility=False)
        minus = extremal_contours(model, forward(model, params - dp), cameras, n_samples=N_SAMPLES, visibility=False)
        fd[:, :, k] = (plus.uv - minus.uv) / (2 * h)
    v = contours.valid
    num = np.linalg.norm((J - fd)[v].reshape(v.sum(), -1), axis=1)
    den = np.linalg.norm(fd[v].reshape(v.sum(), -1), axis=1)
    return float(np.max(num / den))


def run(model_name: str, n_poses: int, repeat: int, seed: int, fd_poses: int) -> dict:
    model = load_model(model_name)
    cameras = ring_cameras(6, size=(800, 600))
    rng = np.random.default_rng(seed)
    t_ct, t_jac, t_render, n_vis, n_pts, fd = [], [], [], [], [], []
    for i in range(n_poses):
        params = model.random_params(rng)
        pose = forward(model, params)
        ct = extremal_contours(model, pose, cameras, n_samples=N_SAMPLES)  # warm-up
        contour_jacobian(model, pose, cameras, ct, rows=ct.visible)
        t_ct.append(best_ms(lambda: extremal_contours(model, pose, cameras, n_samples=N_SAMPLES), repeat))
        t_jac.append(best_ms(lambda: contour_jacobian(model, pose, cameras, ct, rows=ct.visible), repeat))
        if render_silhouettes is not None:
            t_render.append(best_ms(lambda: render_silhouettes(model, pose, cameras), repeat))
        n_vis.append(int(ct.visible.sum()))
        n_pts.append(ct.n_points)
        if i < fd_poses:
            fd.append(fd_error(model, params, cameras, ct))
    ct_ms, jac_ms = np.array(t_ct), np.array(t_jac)  # (n_poses, 2): wall, cpu
    render_ms = np.array(t_render).reshape(-1, 2)
    return {
        "model": model.name,
        "dof": model.n_params,
        "cameras": len(cameras),
        "points": int(np.median(n_pts)),
        "points_visible": float(np.median(n_vis)),
        "max_rel_fd_error": max(fd) if fd else None,
        "ms_contours": float(np.median(ct_ms[:, 0])),
        "ms_jacobian": float(np.median(jac_ms[:, 0])),
        "ms_render_6x800x600": float(np.median(render_ms[:, 0])) if len(render_ms) else None,
        "ms_contours_plus_jacobian": float(np.median(ct_ms[:, 0] + jac_ms[:, 0])),
        "cpu_ms_contours": float(np.median(ct_ms[:, 1])),
        "cpu_ms_jacobian": float(np.median(jac_ms[:, 1])),
        "cpu_ms_contours_plus_jacobian": float(np.median(ct_ms[:, 1] + jac_ms[:, 1])),
        "cpu_ms_render_6x800x600": float(np.median(render_ms[:, 1])) if len(render_ms) else None,
        "poses": n_poses,
        "fd_poses": len(fd),
        "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
        "load_average_1min": os.getloadavg()[0],
        "cpu_count": os.cpu_count(),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="knossow40", help="body model name or file (default knossow40)")
    parser.add_argument("--poses", type=int, default=30, help="random poses (>= 20 for the reported medians)")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per pose; the best counts")
    parser.add_argument("--fd-poses", type=int, default=5, help="poses checked against finite differences")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.poses < 1 or args.repeat < 1 or args.fd_poses < 0:
        parser.error("--poses and --repeat must be >= 1, --fd-poses >= 0")
    ref_ms = machine_ref_ms()
    res = {"machine_ref_ms": ref_ms, **run(args.model, args.poses, args.repeat, args.seed, min(args.fd_poses, args.poses))}
    if args.json:
        print(json.dumps(res))
    else:
        for key, val in res.items():
            print(f"{key:28s} {val:.4g}" if isinstance(val, float) else f"{key:28s} {val}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
