"""A fixed reference workload, timed in the same process as a benchmark.

Machines of one kind differ ~3x in speed, so a benchmark's bare milliseconds cannot be compared
between runs on different machines.  Every benchmark JSON carries ``machine_ref_ms``: the median
wall time of this workload (an exact L2 distance transform of a fixed 800x600 mask, a fixed
1500x40 least-squares step in numpy, a fixed pure-Python loop), measured just before the benchmark.
Quote a benchmark's time as a ratio to it (``ms / machine_ref_ms``) to compare machines.

    from machine_ref import machine_ref_ms      # bench/ is on sys.path for `python bench/x.py`
    ref = machine_ref_ms()
"""

from __future__ import annotations

import time

import cv2
import numpy as np

__all__ = ["machine_ref_ms", "reference_workload"]


def _fixed_inputs() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    mask = np.zeros((600, 800), np.uint8)
    cv2.ellipse(mask, (400, 300), (90, 240), 10.0, 0, 360, 255, -1)
    cv2.rectangle(mask, (250, 150), (560, 190), 255, -1)
    rng = np.random.default_rng(20261125)
    jac = rng.standard_normal((1500, 40))
    res = rng.standard_normal(1500)
    return mask, jac, res


def reference_workload(inputs: tuple[np.ndarray, np.ndarray, np.ndarray]) -> float:
    """Run the workload once and return a checksum (so nothing is optimised away)."""
    mask, jac, res = inputs
    dist = cv2.distanceTransform(255 - mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    hess = jac.T @ jac + 1e-3 * np.eye(jac.shape[1])
    step = np.linalg.solve(hess, jac.T @ res)
    acc = 0
    for i in range(200_000):
        acc = (acc + i * i) % 1_000_003
    return float(dist[300, 10]) + float(step[0]) + acc


def machine_ref_ms(repeats: int = 7) -> float:
    """Median wall time of `reference_workload` over `repeats` runs, in milliseconds."""
    inputs = _fixed_inputs()
    reference_workload(inputs)  # warm caches and OpenCV's dispatch
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        reference_workload(inputs)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times))


if __name__ == "__main__":
    print(f'{{"machine_ref_ms": {machine_ref_ms():.2f}}}')
