"""Chamfer (distance-transform) images and their bilinear sampling with analytic gradient.

Two images per camera frame (Knossow et al., ACCV'06 §3): the distance to the silhouette
(zero inside) and the distance to the edges inside it.  Both are truncated at
``max_distance_px``, quantised to ``resolution_px`` (uint8 when ``max / resolution <= 255``,
else uint16) and cropped to the part of the image where they are below the truncation
(the content's bounding box grown by ``max_distance_px``), with that crop's ``offset_xy``.

Sampling convention: pixel ``(row i, col j)`` of the full image is centred at ``(u, v) = (j, i)``
(OpenCV).  The stored array is extended with the truncation value, so a point more than one
pixel outside the stored region gets exactly the truncation value and zero gradient, and the
interpolated value is continuous everywhere (across the region's rim it blends to the
truncation value within one pixel).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from segmentation.checks import check_finite_array, check_mask
from segmentation.quantise import quantise

__all__ = ["ChamferImages", "ChamferSample", "chamfer_images", "distance_to_mask", "sample_bilinear",
           "quantise", "content_box"]


class ChamferSample(NamedTuple):
    """Sampled distances and their gradients d/d(u, v), pixels.

    Attributes
    ----------
    d_sil : ndarray, shape (n,)
    grad_sil : ndarray, shape (n, 2)
    d_edge : ndarray, shape (n,)
    grad_edge : ndarray, shape (n, 2)
    """

    d_sil: np.ndarray
    grad_sil: np.ndarray
    d_edge: np.ndarray
    grad_edge: np.ndarray


def distance_to_mask(mask: np.ndarray, *, max_distance_px: float, precise: bool = True) -> np.ndarray:
    """Euclidean distance from each pixel to the nearest non-zero pixel of a mask, truncated.

    Parameters
    ----------
    mask : ndarray, shape (h, w), uint8 or bool
    max_distance_px : float
        Truncation, pixels (everywhere when the mask is empty).
    precise : bool
        Exact L2 (the values of OpenCV's ``DIST_MASK_PRECISE``, computed by ``segmentation.edt``);
        False: OpenCV's 5x5 chamfer approximation.

    Returns
    -------
    ndarray, shape (h, w), float32
        0 on the mask.
    """
    mask = check_mask(mask, "mask")
    if not (np.isfinite(max_distance_px) and max_distance_px > 0):
        raise ValueError(f"max_distance_px: expected a finite number > 0, got {max_distance_px!r}")
    if precise:  # the exact transform, truncation-aware (segmentation.edt): OpenCV's values, cheaper
        from segmentation.edt import exact_distance  # numba is imported on first use, not with the package

        return exact_distance(mask, float(max_distance_px))
    if cv2.countNonZero(mask) == 0:  # OpenCV would return ~1e19 (no zero pixel in its input)
        return np.full(mask.shape, max_distance_px, np.float32)
    src = cv2.compare(mask, 0, cv2.CMP_EQ)
    dt = cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_5)
    return cv2.min(dt, float(max_distance_px))


def content_box(masks, *, margin_px: int, region: tuple[int, int, int, int]) -> tuple[int, int, int, int]:
    """Bounding box of the union of masks, grown and clipped.

    Parameters
    ----------
    masks : sequence of ndarray, each shape (h, w), uint8
    margin_px : int
        Growth, pixels.
    region : (int, int, int, int)
        Clip box ``(x0, y0, x1, y1)``.

    Returns
    -------
    (int, int, int, int)
        ``(x0, y0, x1, y1)``; ``(0, 0, 0, 0)`` when every mask is empty.
    """
    boxes = [cv2.boundingRect(m) for m in masks]
    boxes = [b for b in boxes if b[2] > 0 and b[3] > 0]
    if not boxes:
        return 0, 0, 0, 0
    x0 = min(b[0] for b in boxes) - margin_px
    y0 = min(b[1] for b in boxes) - margin_px
    x1 = max(b[0] + b[2] for b in boxes) + margin_px
    y1 = max(b[1] + b[3] for b in boxes) + margin_px
    rx0, ry0, rx1, ry1 = region
    return max(x0, rx0), max(y0, ry0), min(x1, rx1), min(y1, ry1)


def _bilinear_setup(uv: np.ndarray, offset_xy, shape):
    """Flat indices ``(4, n)`` of the 2x2 stencils, their validity ``(4, n)`` and the fractions."""
    h, w = shape
    x = uv[:, 0] - offset_xy[0]
    y = uv[:, 1] - offset_xy[1]
    xf = np.floor(x)
    yf = np.floor(y)
    fx = x - xf
    fy = y - yf
    # clip far-away points first so the integer conversion cannot overflow
    ix = np.clip(xf, -2, w + 1).astype(np.intp)
    iy = np.clip(yf, -2, h + 1).astype(np.intp)
    vx0 = (ix >= 0) & (ix < w)
    vx1 = (ix >= -1) & (ix < w - 1)
    vy0 = (iy >= 0) & (iy < h)
    vy1 = (iy >= -1) & (iy < h - 1)
    cx0 = np.clip(ix, 0, w - 1)
    cx1 = np.clip(ix + 1, 0, w - 1)
    cy0 = np.clip(iy, 0, h - 1) * w
    cy1 = np.clip(iy + 1, 0, h - 1) * w
    idx = np.stack([cy0 + cx0, cy0 + cx1, cy1 + cx0, cy1 + cx1])
    valid = np.stack([vy0 & vx0, vy0 & vx1, vy1 & vx0, vy1 & vx1])
    return idx, valid, fx, fy


def _bilinear_sample(flat: np.ndarray, idx, valid, fx, fy, fill: float):
    """Values ``(n,)`` and gradients ``(n, 2)`` in the units of ``flat``."""
    v = np.where(valid, flat[idx], fill)  # (4, n): v00, v10, v01, v11  (x varies fastest)
    v00, v10, v01, v11 = v
    dx0 = v10 - v00
    dx1 = v11 - v01
    top = v00 + fx * dx0
    bottom = v01 + fx * dx1
    value = top + fy * (bottom - top)
    grad = np.empty((fx.size, 2))
    grad[:, 0] = dx0 + fy * (dx1 - dx0)
    grad[:, 1] = bottom - top
    return value, grad


def _check_uv(uv) -> np.ndarray:
    uv = check_finite_array(uv, "uv", ndim=2)
    if uv.shape[1] != 2:
        raise ValueError(f"uv: expected shape (n, 2), got {uv.shape}")
    return uv.astype(np.float64, copy=False)


def sample_bilinear(image: np.ndarray, uv, *, offset_xy=(0, 0), fill: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear value and gradient of a float image stored at an offset in the full image.

    Outside the stored array the image is ``fill`` (the float path of :meth:`ChamferImages.sample`).

    Parameters
    ----------
    image : ndarray, shape (h, w)
    uv : ndarray, shape (n, 2)
        Full-image pixel coordinates.
    offset_xy : (int, int)
        (x, y) of the array's top-left pixel in the full image.
    fill : float

    Returns
    -------
    value : ndarray, shape (n,)
    grad : ndarray, shape (n, 2)
        d/d(u, v).
    """
    uv = _check_uv(uv)
    image = np.asarray(image, dtype=np.float64)
    if image.size == 0:
        return np.full(len(uv), float(fill)), np.zeros((len(uv), 2))
    idx, valid, fx, fy = _bilinear_setup(uv, offset_xy, image.shape)
    return _bilinear_sample(image.ravel(), idx, valid, fx, fy, float(fill))


@dataclass(frozen=True)
class ChamferImages:
    """Quantised, truncated distance images of one camera frame.

    A ``tracker.fitting.sampler.ChamferSampler`` (``sample``) that also holds the silhouette array
    the tracker's reverse term reads (``SilhouetteChamfer``).

    Attributes
    ----------
    silhouette_q, edges_q : ndarray, shape (h, w), uint8 or uint16
        Same shape; ``value * resolution_px`` is the distance in pixels to the silhouette (0
        inside) / to the nearest edge pixel.
    offset_xy : (int, int)
        (x, y) of the arrays' top-left pixel in the full image.
    resolution_px : float
        Pixels per quantisation step.
    max_distance_px : float
        Truncation distance (a whole number of steps); outside the arrays every distance is this.
    image_size : (int, int)
        (w, h) of the full image.
    """

    silhouette_q: np.ndarray
    edges_q: np.ndarray
    offset_xy: tuple[int, int]
    resolution_px: float
    max_distance_px: float
    image_size: tuple[int, int]

    def __post_init__(self) -> None:
        for name in ("silhouette_q", "edges_q"):
            a = getattr(self, name)
            if not isinstance(a, np.ndarray) or a.ndim != 2 or a.dtype not in (np.uint8, np.uint16):
                raise TypeError(f"{name}: expected a 2-D uint8/uint16 array")
        if self.silhouette_q.shape != self.edges_q.shape or self.silhouette_q.dtype != self.edges_q.dtype:
            raise ValueError("silhouette_q, edges_q: must have the same shape and dtype")
        if not (np.isfinite(self.resolution_px) and self.resolution_px > 0):
            raise ValueError(f"resolution_px: expected > 0, got {self.resolution_px!r}")

    @property
    def max_code(self) -> int:
        return int(round(self.max_distance_px / self.resolution_px))

    def dequantised(self) -> tuple[np.ndarray, np.ndarray]:
        """Float distance images of the stored region, pixels.

        Returns
        -------
        silhouette, edges : ndarray, shape (h, w), float32
        """
        r = np.float32(self.resolution_px)
        return self.silhouette_q.astype(np.float32) * r, self.edges_q.astype(np.float32) * r

    def sample(self, uv) -> ChamferSample:
        """Bilinear distances and gradients at full-image points; never NaN.

        Works directly on the quantised arrays.  See the module docstring for the pixel-centre
        convention and the behaviour outside the stored region.

        Parameters
        ----------
        uv : ndarray, shape (n, 2)
            Pixel coordinates (u, v).

        Returns
        -------
        ChamferSample
            Distances (pixels) and gradients d/d(u, v) to the silhouette and to the edges.
        """
        uv = _check_uv(uv)
        n = len(uv)
        trunc = float(self.max_distance_px)
        if self.silhouette_q.size == 0:
            return ChamferSample(np.full(n, trunc), np.zeros((n, 2)), np.full(n, trunc), np.zeros((n, 2)))
        idx, valid, fx, fy = _bilinear_setup(uv, self.offset_xy, self.silhouette_q.shape)
        fill = float(self.max_code)
        r = float(self.resolution_px)
        ds, gs = _bilinear_sample(self.silhouette_q.ravel(), idx, valid, fx, fy, fill)
        de, ge = _bilinear_sample(self.edges_q.ravel(), idx, valid, fx, fy, fill)
        return ChamferSample(ds * r, gs * r, de * r, ge * r)


def chamfer_images(silhouette: np.ndarray, edges: np.ndarray, *, max_distance_px: float = 48.0,
                   resolution_px: float = 0.25, precise: bool = True, precise_edges: bool | None = None,
                   crop: bool = True, offset_xy=(0, 0), image_size=None) -> ChamferImages:
    """Distance images of a silhouette and an edge map, truncated, quantised and cropped.

    Parameters
    ----------
    silhouette, edges : ndarray, shape (h, w), uint8 or bool
        Masks covering the box at ``offset_xy`` of the full image.
    max_distance_px : float
        Truncation, pixels; a whole number of ``resolution_px`` steps (uint8 storage up to 255
        steps, else uint16 up to 65535).
    resolution_px : float
        Pixels per quantisation step.
    precise, precise_edges : bool, bool or None
        Exact L2 for the silhouette / edge distance, else the 5x5 chamfer mask (approximate:
        docs/tuning.md, "Segmentation"); ``precise_edges`` None: as ``precise``.
    crop : bool
        Keep only the content's box grown by ``max_distance_px`` (exact: everything outside is at
        the truncation value).
    offset_xy : (int, int)
        (x, y) of the masks' top-left pixel in the full image.
    image_size : (int, int), optional
        (w, h) of the full image (default: the masks' size).

    Returns
    -------
    ChamferImages
    """
    sil = check_mask(silhouette, "silhouette")
    edg = check_mask(edges, "edges", shape=sil.shape)
    if not (np.isfinite(resolution_px) and resolution_px > 0):
        raise ValueError(f"resolution_px: expected a finite number > 0, got {resolution_px!r}")
    steps = max_distance_px / resolution_px if np.isfinite(max_distance_px) else np.inf
    if not (max_distance_px > 0 and abs(steps - round(steps)) < 1e-6 and round(steps) <= 65535):
        raise ValueError(f"max_distance_px: expected a positive whole number (<= 65535) of resolution_px "
                         f"steps, got {max_distance_px!r} / {resolution_px!r}")
    dtype = np.uint8 if round(steps) <= 255 else np.uint16
    h, w = sil.shape
    image_size = (w, h) if image_size is None else (int(image_size[0]), int(image_size[1]))
    ox, oy = int(offset_xy[0]), int(offset_xy[1])
    if crop:
        x0, y0, x1, y1 = content_box((sil, edg), margin_px=int(np.ceil(max_distance_px)) + 1, region=(0, 0, w, h))
    else:
        x0, y0, x1, y1 = 0, 0, w, h
    sil_c, edg_c = sil[y0:y1, x0:x1], edg[y0:y1, x0:x1]
    if sil_c.size == 0:
        empty = np.zeros((0, 0), dtype)
        return ChamferImages(empty, empty.copy(), (ox, oy), float(resolution_px), float(max_distance_px), image_size)
    codes = [_codes(m, max_distance_px, resolution_px, dtype, p)
             for m, p in ((sil_c, precise), (edg_c, precise if precise_edges is None else precise_edges))]
    return ChamferImages(codes[0], codes[1], (ox + x0, oy + y0), float(resolution_px), float(max_distance_px),
                         image_size)


def _codes(mask: np.ndarray, max_distance_px: float, resolution_px: float, dtype, precise: bool) -> np.ndarray:
    """``quantise(distance_to_mask(mask, ...))`` of a validated mask (exact: in one compiled pass)."""
    if precise:
        from segmentation.edt import exact_codes  # numba is imported on first use, not with the package

        return exact_codes(mask, float(max_distance_px), float(resolution_px), dtype)
    return quantise(distance_to_mask(mask, max_distance_px=max_distance_px, precise=False),
                    resolution_px=resolution_px, dtype=dtype)
