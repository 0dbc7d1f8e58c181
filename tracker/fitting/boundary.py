"""The observed silhouette boundary the chamfer cost's reverse term pulls on (``tracker.fitting.cost``).

``boundary_samples`` picks pixels on the inner boundary of a camera's silhouette.  A frame set is fitted
many times (a second start, the front/back guard, the limb check, the searches' refinements), each fit
with a new ``ChamferCost`` over the same chamfer objects:
``boundary_rays`` remembers the samples and rays of the last ``MEMO_SIZE`` (chamfer object, camera) pairs by
identity (weak references: nothing is kept alive), so they are computed once per camera image.  The
chamfer objects are immutable (``segmentation.distance.ChamferImages`` is a frozen dataclass whose arrays
nothing writes to).
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict

import cv2
import numpy as np

from capture.camera import Camera

__all__ = ["MEMO_SIZE", "boundary_rays", "boundary_samples"]

#: (chamfer object, camera) pairs whose boundary samples and rays are remembered
MEMO_SIZE = 64

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
_memo: "OrderedDict[tuple, tuple]" = OrderedDict()
_lock = threading.Lock()


def boundary_samples(chamfer, *, max_points: int) -> np.ndarray:
    """Up to ``max_points`` pixels ``(k, 2)`` (u, v) on the inner boundary of the silhouette held by
    a ``ChamferImages`` (its zero-distance region), evenly spread in raster order; ``(0, 2)`` when
    the object holds no silhouette array or the silhouette is empty."""
    q = getattr(chamfer, "silhouette_q", None)
    if q is None or q.size == 0 or max_points < 1:
        return np.zeros((0, 2))
    inside = cv2.compare(q, 0, cv2.CMP_EQ)  # uint8, 255 inside
    border = cv2.subtract(inside, cv2.erode(inside, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=0))
    xy = cv2.findNonZero(border)  # (k, 1, 2) (x, y) in raster order, None when empty
    if xy is None:
        return np.zeros((0, 2))
    xy = xy.reshape(-1, 2)
    # k <= n points spaced (n - 1) / (k - 1) >= 1 apart round to distinct indices
    pick = np.linspace(0, len(xy) - 1, min(max_points, len(xy))).round().astype(np.intp)
    return (xy[pick] + np.asarray(chamfer.offset_xy)).astype(float)


def boundary_rays(chamfer, camera: Camera, *, max_points: int, rays: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``boundary_samples(chamfer, max_points=...)`` (k, 2) and, with ``rays``, the unit world directions of
    their rays through ``camera`` (k, 3) (else (k, 3) zeros), remembered per (chamfer object, camera).

    Parameters
    ----------
    chamfer : ChamferSampler
        Samples come from its ``silhouette_q`` (none without one: nothing is remembered then).
    camera : Camera
    max_points : int
    rays : bool

    Returns
    -------
    samples : ndarray, shape (k, 2)
    directions : ndarray, shape (k, 3)
    """
    if getattr(chamfer, "silhouette_q", None) is None:
        samples = boundary_samples(chamfer, max_points=max_points)
        return samples, np.zeros((len(samples), 3))
    key = (id(chamfer), id(camera), int(max_points))
    with _lock:
        hit = _memo.get(key)
        if hit is not None and hit[0]() is chamfer and hit[1]() is camera and (hit[3] is not None or not rays):
            _memo.move_to_end(key)
            return hit[2], (hit[3] if rays else np.zeros((len(hit[2]), 3)))
    samples = boundary_samples(chamfer, max_points=max_points)
    directions = camera.rays(samples) if rays and len(samples) else np.zeros((len(samples), 3))
    try:
        entry = (weakref.ref(chamfer), weakref.ref(camera), samples, directions if rays else None)
    except TypeError:  # not weak-referenceable: not remembered
        return samples, directions
    samples.setflags(write=False)
    directions.setflags(write=False)
    with _lock:
        _memo[key] = entry
        _memo.move_to_end(key)
        while len(_memo) > MEMO_SIZE:
            _memo.popitem(last=False)
    return samples, directions
