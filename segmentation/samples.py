"""The background test at scattered pixels: the per-sample query of a voxel classifier (BMVC'04 §3.2).

:meth:`BackgroundModel.distance` tests whole images (or boxes).  A voxel-based reconstruction only
looks at a few pixels per voxel projection, so its cost should not grow with the image size:
:func:`background_samples` evaluates the same shadow-relaxed Mahalanobis distance as ``distance``
(module docstring of ``segmentation.background``; without its camouflage window) at given pixels only, and returns
their colours too (the coloured hull keeps a mean colour per view).  It reads the model's
precomputed per-pixel terms (precision, ``K^-1 mu``, ``mu^T K^-1 mu``), so ``update`` is honoured.
The per-sample arithmetic is one compiled loop (numba, cached on disk; :func:`warm_up` compiles it), and
so is the floor test's vote at projected floor points (:func:`floor_vote`, ``segmentation.floor``).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from segmentation.background import BGR2YUV, BackgroundModel
from segmentation.checks import check_image_bgr

__all__ = ["background_samples", "floor_vote", "model_terms", "warm_up"]


@nb.njit(cache=True, nogil=True, boundscheck=False)
def _sample(image, pdiag, pcross, a, big_a, inv_a, yuv, flat, lo, hi, full, terms):
    """The loop of :func:`background_samples` over flat pixel indices ``flat`` (m,) of an image
    (h w, 3) uint8 and the model's terms (h w, 3) / (h w,) float32; ``yuv`` (3, 3) BGR2YUV.
    Returns distance, bgr, plain, ratio (the last two empty unless ``terms``)."""
    m = flat.shape[0]
    d = np.empty(m, np.float32)
    bgr = np.empty((m, 3), np.float32)
    plain = np.empty(m if terms else 0, np.float32)
    ratio = np.empty(m if terms else 0, np.float32)
    for i in range(m):
        f = flat[i]
        c0, c1, c2 = np.float32(image[f, 0]), np.float32(image[f, 1]), np.float32(image[f, 2])
        bgr[i, 0], bgr[i, 1], bgr[i, 2] = c0, c1, c2
        y = yuv[0, 0] * c0 + yuv[0, 1] * c1 + yuv[0, 2] * c2
        u = yuv[1, 0] * c0 + yuv[1, 1] * c1 + yuv[1, 2] * c2
        v = yuv[2, 0] * c0 + yuv[2, 1] * c1 + yuv[2, 2] * c2
        big_c = y * y * pdiag[f, 0] + u * u * pdiag[f, 1] + v * v * pdiag[f, 2]
        if full:
            big_c += y * u * pcross[f, 0] + u * v * pcross[f, 1] + v * y * pcross[f, 2]
        big_b = y * a[f, 0] + u * a[f, 1] + v * a[f, 2]
        ba = big_b * inv_a[f]
        s = min(max(ba, lo), hi)
        di = max(big_c + s * (s * big_a[f] - 2.0 * big_b), 0.0)
        s1 = min(s, 1.0)
        d[i] = di / (s1 * s1)
        if terms:
            ratio[i] = ba
            plain[i] = max(big_c - 2.0 * big_b + big_a[f], 0.0)
    return d, bgr, plain, ratio


@nb.njit(cache=True, nogil=True, boundscheck=False)
def floor_vote(points, ratio, R, t, K, dist, w, h, image, pdiag, pcross, a, big_a, yuv, low, body, shadow, seen):
    """One camera's votes on floor points (the loop of ``segmentation.floor.floor_votes`` for one
    voting camera), added in place to ``body``, ``shadow`` (m,) int32 and ``seen`` (m,) bool.

    points (m, 3) world; ratio (m,) the darkening; R (3, 3), t (3,) world2cam, K (3, 3), dist (5,)
    k1 k2 p1 p2 k3; image (h w, 3) uint8 and the model's flat terms (``segmentation.samples.model_terms``)."""
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    for i in range(points.shape[0]):
        X, Y, Z = points[i, 0], points[i, 1], points[i, 2]
        xc = R[0, 0] * X + R[0, 1] * Y + R[0, 2] * Z + t[0]
        yc = R[1, 0] * X + R[1, 1] * Y + R[1, 2] * Z + t[1]
        zc = R[2, 0] * X + R[2, 1] * Y + R[2, 2] * Z + t[2]
        if not zc > 1e-6:
            continue
        x, y = xc / zc, yc / zc
        u0 = K[0, 0] * x + K[0, 1] * y + K[0, 2]  # undistorted: in the image grown by a quarter
        v0 = K[1, 0] * x + K[1, 1] * y + K[1, 2]
        if not (-0.25 * w < u0 < 1.25 * w and -0.25 * h < v0 < 1.25 * h):
            continue
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        u = np.rint(K[0, 0] * xd + K[0, 1] * yd + K[0, 2])
        v = np.rint(K[1, 1] * yd + K[1, 2])
        if not (0.0 <= u < w and 0.0 <= v < h):
            continue
        seen[i] = True
        f = int(v) * w + int(u)
        c0, c1, c2 = np.float32(image[f, 0]), np.float32(image[f, 1]), np.float32(image[f, 2])
        py = yuv[0, 0] * c0 + yuv[0, 1] * c1 + yuv[0, 2] * c2
        pu = yuv[1, 0] * c0 + yuv[1, 1] * c1 + yuv[1, 2] * c2
        pv = yuv[2, 0] * c0 + yuv[2, 1] * c1 + yuv[2, 2] * c2
        big_c = (py * py * pdiag[f, 0] + pu * pu * pdiag[f, 1] + pv * pv * pdiag[f, 2]
                 + py * pu * pcross[f, 0] + pu * pv * pcross[f, 1] + pv * py * pcross[f, 2])
        big_b = py * a[f, 0] + pu * a[f, 1] + pv * a[f, 2]
        s = ratio[i]
        unchanged = max(big_c - 2.0 * big_b + big_a[f], 0.0)
        darkened = max(big_c - 2.0 * s * big_b + s * s * big_a[f], 0.0)
        if unchanged <= low and unchanged < darkened:
            body[i] += 1
        if darkened <= low and darkened <= unchanged:
            shadow[i] += 1


def model_terms(model: BackgroundModel) -> tuple:
    """The model's per-pixel terms as flat float32 arrays over pixels ``row * w + col``:
    ``(pdiag (h w, 3), pcross (h w, 3), a (h w, 3), big_a (h w,), inv_a (h w,))``: the precision's
    diagonal and doubled off-diagonal (Y,U), (U,V), (V,Y) terms, ``K^-1 mu``, ``mu^T K^-1 mu`` and its
    inverse (``segmentation.background``; ``pcross`` is zero for a diagonal model)."""
    return (model._pdiag.reshape(-1, 3), model._pcross.reshape(-1, 3), model._a.reshape(-1, 3),
            model._big_a.reshape(-1), model._inv_a.reshape(-1))


def background_samples(model: BackgroundModel, image_bgr: np.ndarray, cols: np.ndarray,
                       rows: np.ndarray, *, terms: bool = False) -> tuple:
    """Background distance and colour of pixels ``(rows, cols)`` of ``image_bgr``.

    Parameters
    ----------
    model : BackgroundModel
        The camera's background model (same size as the image).
    image_bgr : ndarray, shape (h, w, 3), uint8
    cols, rows : ndarray of int, shape (m,)
        Pixel coordinates inside the image (``0 <= cols < w``, ``0 <= rows < h``; the caller clips
        them, a pixel outside is a ValueError).
    terms : bool
        Also return the plain distance (no shadow relaxation) and the brightness ratio, as
        :meth:`BackgroundModel.distance_terms` does (for the floor test of shadow-like samples).

    Returns
    -------
    distance : ndarray, shape (m,), float32
        Squared shadow-relaxed Mahalanobis distance, as ``model.distance`` with ``window_px=0`` gives.
    bgr : ndarray, shape (m, 3), float32
        The pixels' colours, BGR levels.
    plain, ratio : ndarray, shape (m,), float32
        With ``terms`` only: the squared distance without the shadow relaxation and the brightness
        ratio ``B / A`` before clipping.
    """
    check_image_bgr(image_bgr, "image_bgr", size=model.size)
    w, h = model.size
    rows, cols = np.asarray(rows, dtype=np.intp).ravel(), np.asarray(cols, dtype=np.intp).ravel()
    if rows.shape != cols.shape:
        raise ValueError(f"background_samples: rows {rows.shape} and cols {cols.shape} differ in length")
    for name, v, n in (("cols", cols, w), ("rows", rows, h)):
        if v.size and (v.min() < 0 or v.max() >= n):
            raise ValueError(f"background_samples: {name} outside 0..{n - 1}: {v.min()}..{v.max()}")
    flat = rows * w + cols
    lo, hi = model.shadow_range
    d, bgr, plain, ratio = _sample(np.ascontiguousarray(image_bgr).reshape(-1, 3), *model_terms(model), BGR2YUV,
                                   flat, float(lo), float(hi), model.covariance == "full", bool(terms))
    return (d, bgr, plain, ratio) if terms else (d, bgr)


def warm_up() -> None:
    """Compile this module's loops (or load them from numba's on-disk cache), for writable and
    read-only images (a frame decoded from the wire may be read-only: another numba signature) and
    the read-only matrices a ``Camera`` holds."""
    plane = np.zeros((1, 3), np.float32)
    one = np.ones(1, np.float32)
    cam = [np.eye(3), np.array([0.0, 0.0, 2.0]), np.eye(3), np.zeros(5)]
    for a in cam:
        a.setflags(write=False)
    for writable in (True, False):
        image = np.zeros((1, 3), np.uint8)
        image.setflags(write=writable)
        for terms in (False, True):
            _sample(image, plane, plane, plane, one, one, BGR2YUV, np.zeros(1, np.intp), 0.5, 1.1, True, terms)
        floor_vote(np.zeros((2, 3)), np.ones(2, np.float32), *cam, 1, 1, image, plane, plane, plane, one, BGR2YUV,
                   16.0, np.zeros(2, np.int32), np.zeros(2, np.int32), np.zeros(2, bool))
