"""Foreground decision and silhouette clean-up.

From the per-pixel background distance ``d`` (:meth:`BackgroundModel.distance`):

1. hysteresis pair: ``weak = d > low``, ``strong = d > high``;
2. morphology on ``weak``: opening (drops specks) then closing (joins small gaps);
3. connected components (outer contours): a component is kept when its area is at least
   ``min_area_px`` (a fraction of the expected person size) *and* it holds a strong pixel
   (the hysteresis: weak pixels survive only when connected to strong ones);
4. holes smaller than ``max_hole_fraction`` of their component's area are filled; bigger ones
   (the gap between an arm and the body) are kept open, with any islands inside them.

Everything works on the region of interest only; the output is a 0/255 uint8 mask.
"""

from __future__ import annotations

import cv2
import numpy as np

from segmentation.checks import check_roi

__all__ = ["silhouette_from_distance", "largest_components"]


def _disk(radius_px: int) -> np.ndarray:
    r = int(radius_px)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def silhouette_from_distance(distance: np.ndarray, *, low: float = 16.0, high: float = 64.0,
                             min_area_px: float = 400.0, max_hole_fraction: float = 0.05,
                             open_px: int = 1, close_px: int = 2, max_components: int | None = None,
                             roi=None) -> np.ndarray:
    """Clean binary silhouette of a background distance image (hysteresis, morphology, components, holes).

    Parameters
    ----------
    distance : ndarray, shape (h, w), float32
        Squared Mahalanobis distance (``BackgroundModel.distance``); must be finite.
    low, high : float
        Hysteresis pair: pixels above ``low`` in components holding a pixel above ``high``.
    min_area_px : float
        Smaller components are dropped, pixels.
    max_hole_fraction : float
        Holes below this fraction of their component's area are filled.
    open_px, close_px : int
        Radii of the morphological opening and closing, pixels (0 skips).
    max_components : int or None
        Keep only that many of the largest components (None: all that pass).
    roi : (int, int, int, int), optional
        ``(x0, y0, x1, y1)``: only that box is processed, the rest of the output is 0.

    Returns
    -------
    ndarray, shape (h, w), uint8
        0 / 255.
    """
    if not isinstance(distance, np.ndarray) or distance.ndim != 2:
        raise ValueError(f"distance: expected a 2-D array, got {getattr(distance, 'shape', type(distance))}")
    if distance.dtype != np.float32:
        raise TypeError(f"distance: expected dtype float32, got {distance.dtype}")
    if not np.isfinite(cv2.sumElems(distance)[0]):  # one pass: NaN / inf make the sum non-finite
        raise ValueError("distance: contains NaN or inf")
    if max_components is not None and max_components < 1:
        raise ValueError(f"max_components: expected None or >= 1, got {max_components!r}")
    return clean_silhouette(distance, low=low, high=high, min_area_px=min_area_px,
                            max_hole_fraction=max_hole_fraction, open_px=open_px, close_px=close_px,
                            max_components=max_components, roi=roi)


def clean_silhouette(distance: np.ndarray, *, low: float, high: float, min_area_px: float,
                     max_hole_fraction: float, open_px: int, close_px: int, max_components: int | None,
                     roi=None) -> np.ndarray:
    """:func:`silhouette_from_distance` without its finiteness pass over ``distance``.

    For callers whose distance is known finite (e.g. :meth:`BackgroundModel.distance` output);
    parameters and result as :func:`silhouette_from_distance`.
    """
    if not (0 <= low <= high) or not np.isfinite(high):
        raise ValueError(f"low, high: expected 0 <= low <= high < inf, got {low!r}, {high!r}")
    h, w = distance.shape
    x0, y0, x1, y1 = check_roi(roi, (w, h))
    d = distance[y0:y1, x0:x1]
    weak = cv2.compare(d, float(low), cv2.CMP_GT)
    if open_px > 0:
        weak = cv2.morphologyEx(weak, cv2.MORPH_OPEN, _disk(open_px))
    if close_px > 0:
        weak = cv2.morphologyEx(weak, cv2.MORPH_CLOSE, _disk(close_px))
    out = np.zeros((h, w), np.uint8)
    out[y0:y1, x0:x1] = _keep_components(weak, d, high=float(high), min_area_px=float(min_area_px),
                                         max_hole_fraction=float(max_hole_fraction), max_components=max_components)
    return out


def _keep_components(weak: np.ndarray, d: np.ndarray, *, high: float, min_area_px: float,
                     max_hole_fraction: float, max_components: int | None) -> np.ndarray:
    """Components of ``weak`` big enough and holding a pixel with ``d > high``; holes smaller than
    ``max_hole_fraction`` of their component's area filled; islands inside kept holes kept."""
    contours, hierarchy = cv2.findContours(weak, cv2.RETR_TREE, cv2.CHAIN_APPROX_SIMPLE)
    out = np.zeros_like(weak)
    if not contours:
        return out
    hier = hierarchy[0]  # (n, 4): next, previous, first child, parent
    kept = []
    for i in np.flatnonzero(hier[:, 3] < 0):  # loop over components (few after the opening), not pixels
        area = cv2.contourArea(contours[i])
        if area < min_area_px:
            continue
        x, y, bw, bh = cv2.boundingRect(contours[i])
        comp = np.zeros((bh, bw), np.uint8)
        cv2.drawContours(comp, contours, int(i), 255, thickness=cv2.FILLED, offset=(-x, -y))
        if cv2.minMaxLoc(d[y:y + bh, x:x + bw], mask=comp)[1] <= high:
            continue  # hysteresis: no strong pixel in this component
        kept.append((area, int(i)))
    kept.sort(reverse=True)
    for area, i in kept[:max_components]:
        _draw_component(out, contours, hier, i, area * max_hole_fraction)
    return out


def _draw_component(out, contours, hier, i: int, max_hole_area_px: float) -> None:
    """Fill outer contour ``i``; re-open its big holes and redraw the islands inside them."""
    stack = [i]
    while stack:  # depth of nesting, not pixels
        k = stack.pop()
        cv2.drawContours(out, contours, k, 255, thickness=cv2.FILLED)
        hole = hier[k, 2]
        while hole >= 0:
            if cv2.contourArea(contours[hole]) >= max_hole_area_px:
                cv2.drawContours(out, contours, int(hole), 0, thickness=cv2.FILLED)
                cv2.drawContours(out, contours, int(hole), 255, thickness=1)  # the hole's rim is silhouette
                island = hier[hole, 2]
                while island >= 0:
                    stack.append(int(island))
                    island = hier[island, 0]
            hole = hier[hole, 0]


def largest_components(mask: np.ndarray, *, count: int = 2) -> np.ndarray:
    """Pixel areas of the largest 8-connected components of a mask, for statistics and tests.

    Parameters
    ----------
    mask : ndarray, shape (h, w)
        Non-zero = foreground.
    count : int
        How many.

    Returns
    -------
    ndarray of int, shape (count,)
        Descending; zero-padded.
    """
    n, _, stats, _ = cv2.connectedComponentsWithStats((mask > 0).astype(np.uint8), connectivity=8)
    areas = np.sort(stats[1:, cv2.CC_STAT_AREA])[::-1]
    return np.pad(areas[:count], (0, max(0, count - areas.size)))
