"""Exact truncated Euclidean distance transform of a mask (compiled with numba).

The same values as OpenCV's ``cv2.distanceTransform(..., DIST_L2, DIST_MASK_PRECISE)`` followed
by ``cv2.min(., max_distance_px)`` (float32 square roots of the exact integer squared distances),
in one pass that skips what the truncation makes irrelevant.  Two phases (Meijster et al. 2000,
Felzenszwalb & Huttenlocher 2012):

1. per column, the vertical distance ``g`` to the nearest mask pixel, saturated at
   ``ceil(max_distance_px) + 1`` (a pixel that far from every mask pixel of its column can only be
   at the truncation), branch-free over whole rows (vectorised by the compiler);
2. per row, the lower envelope of the parabolas ``(x - u)^2 + g(u)^2`` over the columns ``u`` with an
   unsaturated ``g``; the exact integer squared distance is read off the envelope and mapped
   through a table of its truncated distance (or of that distance's quantised code,
   :func:`exact_codes`), so no square root or quantisation pass is left per pixel.

Truncations above ``MAX_TABLE_PX`` (a table of ``MAX_TABLE_PX ** 2`` entries) use OpenCV's
precise transform instead.  Compiled on first use and cached on disk (``cache=True``);
:func:`warm_up` triggers it.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numba as nb
import numpy as np

from segmentation.quantise import quantise

__all__ = ["exact_distance", "exact_codes", "warm_up", "MAX_TABLE_PX"]

MAX_TABLE_PX = 1024  # largest truncation (pixels) served by the table-driven kernel


@nb.njit(cache=True, nogil=True, boundscheck=False)
def _edt(mask, cap, table, out):  # pragma: no cover - compiled; exercised through exact_distance / exact_codes
    h, w = mask.shape
    g = np.empty((h, w), np.int16)
    c = np.int16(cap)
    one = np.int16(1)
    zero = np.int16(0)
    row, cur = mask[0], g[0]
    for x in range(w):
        cur[x] = zero if row[x] != 0 else c
    for y in range(1, h):
        prev, cur, row = g[y - 1], g[y], mask[y]
        for x in range(w):
            cur[x] = zero if row[x] != 0 else min(prev[x] + one, c)
    for y in range(h - 2, -1, -1):
        nxt, cur = g[y + 1], g[y]
        for x in range(w):
            cur[x] = min(cur[x], nxt[x] + one)
    sites = np.empty(w, np.int64)
    heights = np.empty(w, np.int64)  # g(u)^2 + u^2 of each site
    bounds = np.empty(w + 1, np.float64)
    last = table.size - 1
    far = table[last]
    for y in range(h):
        k = -1  # index of the last parabola of the envelope
        gy, o = g[y], out[y]
        for q in range(w):
            gq = np.int64(gy[q])
            if gq >= cap:
                continue
            fq = gq * gq + q * q
            s = -1e30
            while k >= 0:
                s = (fq - heights[k]) / (2.0 * (q - sites[k]))
                if s > bounds[k]:
                    break
                k -= 1
            k += 1
            sites[k] = q
            heights[k] = fq
            bounds[k] = s if k > 0 else -1e30
            bounds[k + 1] = 1e30
        if k < 0:
            for x in range(w):
                o[x] = far
            continue
        j = 0
        p = sites[0]
        gp2 = heights[0] - p * p
        nxt_bound = bounds[1]
        for x in range(w):
            if nxt_bound < x:
                while bounds[j + 1] < x:
                    j += 1
                p = sites[j]
                gp2 = heights[j] - p * p
                nxt_bound = bounds[j + 1]
            d2 = (x - p) * (x - p) + gp2
            o[x] = table[d2 if d2 < last else last]


@lru_cache(maxsize=16)
def _table(max_distance_px: float, resolution_px: float | None, dtype: str) -> np.ndarray:
    """Truncated float32 distance (``resolution_px`` None) or its quantised code for every squared
    distance ``0 .. ceil(max_distance_px)^2`` (the last entry: the truncation)."""
    n = int(np.ceil(max_distance_px))
    d = np.sqrt(np.arange(n * n + 1, dtype=np.float32)).astype(np.float32)
    d = np.minimum(d, np.float32(max_distance_px))
    if resolution_px is None:
        return d
    return np.ascontiguousarray(quantise(d.reshape(1, -1), resolution_px=resolution_px, dtype=np.dtype(dtype)).ravel())


def _opencv(mask: np.ndarray, max_distance_px: float) -> np.ndarray:
    if cv2.countNonZero(mask) == 0:
        return np.full(mask.shape, max_distance_px, np.float32)
    dt = cv2.distanceTransform(cv2.compare(mask, 0, cv2.CMP_EQ), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return cv2.min(dt, float(max_distance_px))


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
    if max_distance_px > MAX_TABLE_PX:
        return _opencv(mask, float(max_distance_px))
    out = np.empty(mask.shape, np.float32)
    if mask.size:
        _edt(mask, int(np.ceil(max_distance_px)) + 1, _table(float(max_distance_px), None, "float32"), out)
    return out


def exact_codes(mask: np.ndarray, max_distance_px: float, resolution_px: float, dtype) -> np.ndarray:
    """``quantise(exact_distance(mask, max_distance_px), resolution_px=..., dtype=...)`` in one pass.

    Parameters
    ----------
    mask : ndarray, shape (h, w), uint8
        Non-zero = the set the distance is taken to (validated by the caller).
    max_distance_px, resolution_px : float
        Truncation and pixels per quantisation step (> 0; the codes must fit ``dtype``).
    dtype : numpy.uint8 or numpy.uint16

    Returns
    -------
    ndarray, shape (h, w), ``dtype``
    """
    mask = np.ascontiguousarray(mask)
    if max_distance_px > MAX_TABLE_PX:
        return quantise(_opencv(mask, float(max_distance_px)), resolution_px=resolution_px, dtype=dtype)
    table = _table(float(max_distance_px), float(resolution_px), np.dtype(dtype).name)
    out = np.empty(mask.shape, table.dtype)
    if mask.size:
        _edt(mask, int(np.ceil(max_distance_px)) + 1, table, out)
    return out


def warm_up() -> None:
    """Compile (or load from the cache) the kernel, e.g. before a live worker's first frame."""
    exact_distance(np.zeros((2, 2), np.uint8), 1.0)
    exact_codes(np.zeros((2, 2), np.uint8), 1.0, 0.25, np.uint8)
