"""Edges inside the silhouette (Knossow et al., ACCV'06 §3): Canny on luminance within the
dilated silhouette, plus the silhouette boundary.

Only the bounding box of the dilated silhouette is converted, blurred and run through Canny,
so the cost follows the person's size, not the image's.
"""

from __future__ import annotations

import cv2
import numpy as np

from segmentation.checks import check_mask

__all__ = ["silhouette_edges", "silhouette_boundary"]

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def silhouette_boundary(silhouette: np.ndarray) -> np.ndarray:
    """Inner boundary of a silhouette: its pixels with a 4-neighbour outside it.

    Parameters
    ----------
    silhouette : ndarray, shape (h, w), uint8 or bool
        Non-zero = body.

    Returns
    -------
    ndarray, shape (h, w), uint8
        0 / 255.
    """
    sil = check_mask(silhouette, "silhouette")
    sil = cv2.compare(sil, 0, cv2.CMP_GT)
    return cv2.subtract(sil, cv2.erode(sil, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=0))


def silhouette_edges(image: np.ndarray, silhouette: np.ndarray, *, low: float = 30.0, high: float = 90.0,
                     dilate_px: int = 3, blur_sigma: float = 1.0, boundary: bool = True) -> np.ndarray:
    """Canny edges inside the dilated silhouette, plus (``boundary``) its inner boundary.

    Parameters
    ----------
    image : ndarray, shape (h, w) or (h, w, 3), uint8
        Luminance, or BGR (converted to grey on the crop).
    silhouette : ndarray, shape (h, w), uint8 or bool
    low, high : float
        Canny hysteresis thresholds on the Sobel gradient magnitude (L1).
    dilate_px : int
        Dilation of the silhouette before the edges are kept, pixels.
    blur_sigma : float
        Gaussian blur before Canny, pixels (0 skips it).
    boundary : bool
        Add the silhouette's inner boundary.

    Returns
    -------
    ndarray, shape (h, w), uint8
        0 / 255 edge map.
    """
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise TypeError(f"image: expected a uint8 numpy array, got {getattr(image, 'dtype', type(image))}")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ValueError(f"image: expected shape (h, w) or (h, w, 3), got {image.shape}")
    sil = check_mask(silhouette, "silhouette", shape=image.shape[:2])
    if not 0 <= low <= high:
        raise ValueError(f"low, high: expected 0 <= low <= high, got {low!r}, {high!r}")
    h, w = sil.shape
    out = np.zeros((h, w), np.uint8)
    bx, by, bw, bh = cv2.boundingRect(sil)
    if bw == 0 or bh == 0:
        return out
    pad = int(dilate_px) + 3  # room for the dilation and Canny's 3x3 / blur support
    x0, y0 = max(bx - pad, 0), max(by - pad, 0)
    x1, y1 = min(bx + bw + pad, w), min(by + bh + pad, h)
    crop = image[y0:y1, x0:x1]
    gray = cv2.cvtColor(crop, cv2.COLOR_BGR2GRAY) if crop.ndim == 3 else crop
    if blur_sigma > 0:
        gray = cv2.GaussianBlur(gray, (0, 0), float(blur_sigma))
    edges = cv2.Canny(gray, float(low), float(high))
    sil_crop = cv2.compare(sil[y0:y1, x0:x1], 0, cv2.CMP_GT)
    if dilate_px > 0:
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * int(dilate_px) + 1,) * 2)
        region = cv2.dilate(sil_crop, k)
    else:
        region = sil_crop
    edges = cv2.bitwise_and(edges, region)
    if boundary:
        edges = cv2.bitwise_or(edges, silhouette_boundary(sil_crop))
    out[y0:y1, x0:x1] = edges
    return out
