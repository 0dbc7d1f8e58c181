"""The background test at scattered pixels: the per-sample query of a voxel classifier (BMVC'04 §3.2).

:meth:`BackgroundModel.distance` tests whole images (or boxes).  A voxel-based reconstruction only
looks at a few pixels per voxel projection, so its cost should not grow with the image size:
:func:`background_samples` evaluates the same shadow-relaxed Mahalanobis distance as ``distance``
(module docstring of ``segmentation.background``; without its camouflage window) at given pixels only, and returns
their colours too (the coloured hull keeps a mean colour per view).  It reads the model's
precomputed per-pixel terms (precision, ``K^-1 mu``, ``mu^T K^-1 mu``), so ``update`` is honoured.
"""

from __future__ import annotations

import numpy as np

from segmentation.background import BGR2YUV, BackgroundModel
from segmentation.checks import check_image_bgr

__all__ = ["background_samples"]


def background_samples(model: BackgroundModel, image_bgr: np.ndarray, cols: np.ndarray,
                       rows: np.ndarray, *, terms: bool = False) -> tuple:
    """Background distance and colour of pixels ``(rows, cols)`` of ``image_bgr``.

    Parameters
    ----------
    model : BackgroundModel
        The camera's background model (same size as the image).
    image_bgr : ndarray, shape (h, w, 3), uint8
    cols, rows : ndarray of int, shape (m,)
        Pixel coordinates, already inside the image (``0 <= cols < w``, ``0 <= rows < h``); the
        caller clips them (this runs per voxel level, so it does not check every value).
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
    w = model.size[0]
    flat = np.asarray(rows, dtype=np.intp) * w + np.asarray(cols, dtype=np.intp)
    bgr = image_bgr.reshape(-1, 3)[flat].astype(np.float32)
    p = bgr @ BGR2YUV.T  # centred YUV, (m, 3)
    pdiag = model._pdiag.reshape(-1, 3)[flat]
    big_c = np.einsum("mi,mi->m", p * p, pdiag)
    if model.covariance == "full":
        q = p[:, [1, 2, 0]]  # pairs (Y,U), (U,V), (V,Y)
        big_c += np.einsum("mi,mi->m", p * q, model._pcross.reshape(-1, 3)[flat])
    big_b = np.einsum("mi,mi->m", p, model._a.reshape(-1, 3)[flat])
    big_a = model._big_a.reshape(-1)[flat]
    lo, hi = model.shadow_range
    s = np.clip(big_b * model._inv_a.reshape(-1)[flat], lo, hi)
    d = np.maximum(big_c + s * (s * big_a - 2.0 * big_b), 0.0)
    s1 = np.minimum(s, 1.0)
    if not terms:
        return (d / (s1 * s1)).astype(np.float32), bgr
    ratio = big_b * model._inv_a.reshape(-1)[flat]
    plain = np.maximum(big_c - 2.0 * big_b + big_a, 0.0)
    return (d / (s1 * s1)).astype(np.float32), bgr, plain.astype(np.float32), ratio.astype(np.float32)
