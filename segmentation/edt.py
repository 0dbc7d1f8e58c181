"""Exact truncated Euclidean distance transform of a mask (compiled with numba).

The same values as OpenCV's ``cv2.distanceTransform(..., DIST_L2, DIST_MASK_PRECISE)`` followed
by ``cv2.min(., max_distance_px)`` (float32 square roots of the exact integer squared distances),
in one pass that skips what the truncation makes irrelevant.  Two phases (Meijster et al. 2000,
Felzenszwalb & Huttenlocher 2012):

1. per column, the vertical distance ``g`` to the nearest mask pixel, saturated at
   ``ceil(max_distance_px) + 1`` (a pixel that far from every mask pixel of its column can only be
   at the truncation);
2. per row, the lower envelope of the parabolas ``(x - u)^2 + g(u)^2`` over the columns ``u`` with an
   unsaturated ``g``; the squared distance is read off the envelope and truncated.

Rows are processed in memory order (phase 1 scans whole rows), so the cost is a few operations
per pixel.  Compiled on first use and cached on disk (``cache=True``); :func:`warm_up` triggers it.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["exact_distance", "warm_up"]


@nb.njit(cache=True, nogil=True, boundscheck=False)
def _edt(mask, max_px, out):  # pragma: no cover - compiled; exercised through exact_distance
    h, w = mask.shape
    cap = int(np.ceil(max_px)) + 1
    g = np.empty((h, w), np.int32)
    for x in range(w):
        g[0, x] = 0 if mask[0, x] else cap
    for y in range(1, h):
        for x in range(w):
            if mask[y, x]:
                g[y, x] = 0
            else:
                v = g[y - 1, x] + 1
                g[y, x] = v if v < cap else cap
    for y in range(h - 2, -1, -1):
        for x in range(w):
            v = g[y + 1, x] + 1
            if v < g[y, x]:
                g[y, x] = v
    sites = np.empty(w, np.int32)
    bounds = np.empty(w + 1, np.float64)
    trunc = np.float32(max_px)
    for y in range(h):
        k = -1  # index of the last parabola of the envelope
        for q in range(w):
            gq = g[y, q]
            if gq >= cap:
                continue
            fq = gq * gq + q * q
            s = -1e30
            while k >= 0:
                p = sites[k]
                s = (fq - (g[y, p] * g[y, p] + p * p)) / (2.0 * (q - p))
                if s > bounds[k]:
                    break
                k -= 1
            k += 1
            sites[k] = q
            bounds[k] = s if k > 0 else -1e30
            bounds[k + 1] = 1e30
        if k < 0:
            for x in range(w):
                out[y, x] = trunc
            continue
        j = 0
        for x in range(w):
            while bounds[j + 1] < x:
                j += 1
            p = sites[j]
            d = np.float32(np.sqrt(np.float32((x - p) * (x - p) + g[y, p] * g[y, p])))
            out[y, x] = d if d < trunc else trunc


def exact_distance(mask: np.ndarray, max_distance_px: float) -> np.ndarray:
    """Euclidean distance of every pixel to the nearest non-zero pixel of ``mask``, truncated.

    Parameters
    ----------
    mask : ndarray, shape (h, w), uint8
        Non-zero = the set the distance is taken to (validated by the caller).
    max_distance_px : float
        Truncation, pixels (> 0); every pixel when the mask is empty.

    Returns
    -------
    ndarray, shape (h, w), float32
        0 on the mask.
    """
    mask = np.ascontiguousarray(mask)
    out = np.empty(mask.shape, np.float32)
    if mask.size:
        _edt(mask, float(max_distance_px), out)
    return out


def warm_up() -> None:
    """Compile (or load from the cache) the kernel, e.g. before a live worker's first frame."""
    exact_distance(np.zeros((2, 2), np.uint8), 1.0)
