"""One call per camera frame: background test -> silhouette -> edges -> chamfer images."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from segmentation.background import BackgroundModel
from segmentation.checks import check_image_bgr, check_roi
from segmentation.distance import ChamferImages, chamfer_images
from segmentation.edges import silhouette_edges
from segmentation.silhouette import clean_silhouette

__all__ = ["FrameSegmentation", "SegmentationParams", "segment_frame"]


@dataclass(frozen=True)
class SegmentationParams:
    """Options of :func:`segment_frame` (defaults tuned on uu_studio and the synthetic scenes).

    Measurements behind the defaults: docs/tuning.md, "Segmentation".

    Parameters
    ----------
    low, high : float
        Hysteresis pair on the squared Mahalanobis distance.
    person_area_px : float or None
        Expected person area in pixels (None: a fiftieth of the image).
    min_area_fraction : float
        Components below this fraction of ``person_area_px`` are dropped.
    max_hole_fraction : float
        Holes below this fraction of their component's area are filled.
    open_px, close_px : int
        Radii of the morphological opening / closing, pixels.
    max_components : int or None
        Keep only the largest N components (None: all that pass; 1 suits one person in a
        cluttered studio and keeps the chamfer crop small).
    canny_low, canny_high, edge_dilate_px, blur_sigma : float, float, int, float
        Edge detection inside the silhouette (:func:`silhouette_edges`).
    auto_roi, auto_roi_margin_px : bool, int
        Without a ``roi``, find one with a half-resolution pass and process only the box around
        what it finds, grown by the margin in pixels; nothing found: an empty segmentation.
    floor_test : bool
        Offline callers holding a whole frame set apply ``segmentation.floor`` (live workers see one camera).
    max_distance_px, resolution_px, precise, precise_edges : float, float, bool, bool
        Chamfer images (:func:`chamfer_images`); by default the edge distance uses the cheaper
        5x5 chamfer mask (edges are noisy anyway).
    """

    low: float = 16.0
    high: float = 64.0
    person_area_px: float | None = None
    min_area_fraction: float = 0.2
    max_hole_fraction: float = 0.05
    open_px: int = 1
    close_px: int = 1
    max_components: int | None = None
    canny_low: float = 30.0
    canny_high: float = 90.0
    edge_dilate_px: int = 3
    blur_sigma: float = 1.0
    max_distance_px: float = 48.0
    resolution_px: float = 0.25
    precise: bool = True
    precise_edges: bool = False
    auto_roi: bool = True
    auto_roi_margin_px: int = 16
    floor_test: bool = False

    def __post_init__(self) -> None:
        # the options a wrong value would turn into silently empty or unbounded output (the rest are
        # checked where they are used: low/high, Canny, the chamfer resolution)
        if self.max_components is not None and self.max_components < 1:
            raise ValueError(f"max_components: expected None or >= 1, got {self.max_components!r}")
        if self.person_area_px is not None and not self.person_area_px > 0:
            raise ValueError(f"person_area_px: expected None or > 0, got {self.person_area_px!r}")
        for name in ("min_area_fraction", "max_hole_fraction", "open_px", "close_px", "edge_dilate_px",
                     "auto_roi_margin_px"):
            if not getattr(self, name) >= 0:  # NaN too
                raise ValueError(f"{name}: expected >= 0, got {getattr(self, name)!r}")

    def min_area_px(self, image_size: tuple[int, int]) -> float:
        """Smallest component kept, pixels, for an image of ``image_size = (w, h)``."""
        person = self.person_area_px if self.person_area_px is not None else 0.02 * image_size[0] * image_size[1]
        return self.min_area_fraction * person


@dataclass(frozen=True)
class FrameSegmentation:
    """Result of :func:`segment_frame` for one camera frame.

    Attributes
    ----------
    silhouette_roi, edges_roi : ndarray, shape (y1 - y0, x1 - x0), uint8
        0 / 255, the processed box.
    chamfer : ChamferImages
        The quantised distance images (cropped, with offset).
    foreground_fraction : float
        Silhouette pixels / image pixels.
    roi : (int, int, int, int)
        ``(x0, y0, x1, y1)`` processed at full resolution ((0, 0, 0, 0): the automatic ROI's first
        pass found nothing).
    image_size : (int, int)
        ``(w, h)`` of the frame.
    silhouette, edges : ndarray, shape (h, w), uint8
        0 / 255, full image (zero outside the ROI), built on first use (the live path needs the
        chamfer images only).
    """

    silhouette_roi: np.ndarray
    edges_roi: np.ndarray
    chamfer: ChamferImages
    foreground_fraction: float
    roi: tuple[int, int, int, int]
    image_size: tuple[int, int]

    def _full(self, part: np.ndarray) -> np.ndarray:
        w, h = self.image_size
        out = np.zeros((h, w), np.uint8)
        x0, y0, x1, y1 = self.roi
        out[y0:y1, x0:x1] = part
        return out

    @cached_property
    def silhouette(self) -> np.ndarray:
        return self._full(self.silhouette_roi)

    @cached_property
    def edges(self) -> np.ndarray:
        return self._full(self.edges_roi)


def segment_frame(model: BackgroundModel, image_bgr: np.ndarray, *, roi=None,
                  params: SegmentationParams | None = None, cut=None, floor=None) -> FrameSegmentation:
    """Segment one frame against a background model: silhouette, edges and chamfer images.

    Does not adapt the model (call ``model.update`` for that).

    Parameters
    ----------
    model : BackgroundModel
    image_bgr : ndarray, shape (h, w, 3), uint8
    roi : (int, int, int, int), optional
        ``(x0, y0, x1, y1)``: only that box is processed (default: the automatic ROI of ``params``).
    params : SegmentationParams, optional
    cut : callable (silhouette_roi, box) -> silhouette_roi, optional
        Edits the silhouette of the box before the edges and chamfer images are made
        (``segmentation.clutter``).
    floor : callable (box, distance, plain, ratio) -> distance, optional
        The multi-view floor test of shadow-like pixels (``segmentation.floor.FloorShadows.for_camera``);
        with it the automatic ROI also covers shadow-like pixels.

    Returns
    -------
    FrameSegmentation
    """
    params = params or SegmentationParams()
    check_image_bgr(image_bgr, "image_bgr", size=model.size)
    w, h = model.size
    x0, y0, x1, y1 = box = check_roi(roi, (w, h))
    if roi is None and params.auto_roi:
        found = _auto_roi(model, image_bgr, params, plain=floor is not None)
        if found is None:
            return _empty(params, (w, h))
        x0, y0, x1, y1 = box = found
    if floor is None:
        d = model.distance(image_bgr, roi=box)
    else:
        d = floor(box, *model.distance_terms(image_bgr, roi=box))
    sil_roi = clean_silhouette(d, low=params.low, high=params.high, min_area_px=params.min_area_px((w, h)),
                               max_hole_fraction=params.max_hole_fraction, open_px=params.open_px,
                               close_px=params.close_px, max_components=params.max_components)
    if cut is not None:
        sil_roi = cut(sil_roi, box)
    edges_roi = silhouette_edges(image_bgr[y0:y1, x0:x1], sil_roi, low=params.canny_low,
                                 high=params.canny_high, dilate_px=params.edge_dilate_px,
                                 blur_sigma=params.blur_sigma)
    chamfer = chamfer_images(sil_roi, edges_roi, max_distance_px=params.max_distance_px,
                             resolution_px=params.resolution_px, precise=params.precise,
                             precise_edges=params.precise_edges,
                             offset_xy=(x0, y0), image_size=(w, h))
    fraction = float(cv2.countNonZero(sil_roi)) / float(w * h)
    return FrameSegmentation(sil_roi, edges_roi, chamfer, fraction, box, (w, h))


def _auto_roi(model: BackgroundModel, image_bgr: np.ndarray, params: SegmentationParams, plain: bool = False):
    """Box ``(x0, y0, x1, y1)`` around the foreground found at half resolution, or None (``plain``:
    without the shadow relaxation)."""
    w, h = model.size
    d_small = model.coarse_distance(image_bgr, plain=plain)
    sil = clean_silhouette(d_small, low=params.low, high=params.high,
                           min_area_px=params.min_area_px((w, h)) / 4.0, max_hole_fraction=1.0,
                           open_px=0, close_px=1, max_components=params.max_components)
    bx, by, bw, bh = cv2.boundingRect(sil)
    if bw == 0 or bh == 0:
        return None
    m = int(params.auto_roi_margin_px)
    return max(2 * bx - m, 0), max(2 * by - m, 0), min(2 * (bx + bw) + m, w), min(2 * (by + bh) + m, h)


def _empty(params: SegmentationParams, size: tuple[int, int]) -> FrameSegmentation:
    w, h = size
    nothing = np.zeros((1, 1), np.uint8)
    chamfer = chamfer_images(nothing, nothing, max_distance_px=params.max_distance_px,
                             resolution_px=params.resolution_px, image_size=(w, h))
    return FrameSegmentation(np.zeros((0, 0), np.uint8), np.zeros((0, 0), np.uint8), chamfer, 0.0, (0, 0, 0, 0), (w, h))
