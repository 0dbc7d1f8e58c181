"""Foreground that is not the body: operator ignore regions and learned static clutter.

A real silhouette holds things the background model does not know: the chair the subject sits
on, a board moved after the empty-room recording, a box beside the subject.  Every such pixel
pulls on the body model (the reverse term of ``tracker.fitting.cost`` pulls the nearest limb
onto its outline) and lowers the silhouette IoU of the quality gate.  This module decides, per
camera and per pixel, which foreground is *clutter* and removes it from the silhouette before
the edges and chamfer images are made:

* **ignore regions** (``--ignore-region cam:x,y,w,h``, ``[[camera]] ignore = [[x, y, w, h]]`` in
  ``session.toml``): rectangles the operator marks as never body;
* **static clutter** (:class:`StaticClutter`): a pixel that is foreground, *not* covered by the
  fitted model's projection (grown by a margin) and unchanged in colour for ``learn_frames``
  frames in a row becomes clutter; it stops being clutter as soon as it is background again
  (the object was taken away).  A still person is static too: the model's projection keeps the
  body's pixels out of the count (``explained``), so the learner must only be fed frames whose
  fit is trusted (the caller's decision, ``tracker.fitting.scene``).

:func:`without_clutter` applies a mask at the pixels the current body projection does not
cover (a body part moving in front of learned clutter stays body) and drops the fragments the
cut leaves (components below a minimum area).  :func:`segment_without_clutter` is
``segmentation.pipeline.segment_frame`` with that step between the silhouette and the edges.
"""

from __future__ import annotations

import re
from typing import Iterable, Mapping, Sequence

import cv2
import numpy as np

from segmentation.background import BackgroundModel
from segmentation.checks import check_image_bgr
from segmentation.pipeline import FrameSegmentation, SegmentationParams, segment_frame

from segmentation.errors import SegmentationError


class ClutterError(SegmentationError, ValueError):
    """A bad ignore region or clutter-model input; the message names it."""

__all__ = ["StaticClutter", "parse_ignore_region", "ignore_mask", "ignore_masks", "without_clutter",
           "segment_without_clutter", "session_ignore_regions"]

_REGION = re.compile(r"^\s*([^:\s]+)\s*:\s*(-?\d+)\s*,\s*(-?\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*$")


def parse_ignore_region(text: str) -> tuple[str, tuple[int, int, int, int]]:
    """``"cam:x,y,w,h"`` (pixels) -> ``(camera name, (x, y, w, h))``; ValueError otherwise."""
    m = _REGION.match(str(text))
    if m is None:
        raise ClutterError(f"--ignore-region: expected CAMERA:x,y,w,h in pixels, got {text!r}")
    x, y, w, h = (int(v) for v in m.groups()[1:])
    if w <= 0 or h <= 0:
        raise ClutterError(f"--ignore-region {text!r}: width and height must be > 0")
    return m.group(1), (x, y, w, h)


def ignore_mask(size: tuple[int, int], regions: Iterable[Sequence[int]]) -> np.ndarray:
    """Boolean mask ``(h, w)`` of an image of ``size = (w, h)``, True inside the rectangles
    ``(x, y, w, h)`` (clipped to the image)."""
    w, h = int(size[0]), int(size[1])
    out = np.zeros((h, w), bool)
    for reg in regions:
        if len(reg) != 4:
            raise ClutterError(f"ignore region: expected [x, y, w, h], got {list(reg)!r}")
        x, y, rw, rh = (int(v) for v in reg)
        if rw <= 0 or rh <= 0:
            raise ClutterError(f"ignore region {list(reg)!r}: width and height must be > 0")
        out[max(y, 0):max(min(y + rh, h), 0), max(x, 0):max(min(x + rw, w), 0)] = True
    return out


class StaticClutter:
    """Per-pixel learner of static foreground the body model does not explain (one camera).

    Parameters
    ----------
    size : (w, h) of the camera's images
    learn_frames : frames in a row a pixel must be unexplained, static foreground to become clutter
    colour_tol : largest change of a pixel between two fed frames (sum of the absolute BGR
        differences, 0-765) that still counts as unchanged

    Attributes
    ----------
    mask : (h, w) bool, the learned clutter
    frames : frames fed to ``update``
    """

    def __init__(self, size: tuple[int, int], *, learn_frames: int = 25, colour_tol: float = 40.0) -> None:
        if learn_frames < 1:
            raise ClutterError(f"learn_frames: expected >= 1, got {learn_frames!r}")
        w, h = int(size[0]), int(size[1])
        self.size = (w, h)
        self.learn_frames = int(learn_frames)
        self.colour_tol = float(colour_tol)
        self._count = np.zeros((h, w), np.uint16)
        self._last: np.ndarray | None = None
        self._box: tuple[int, int, int, int] | None = None
        self.mask = np.zeros((h, w), bool)
        self.frames = 0

    def update(self, image_bgr: np.ndarray, foreground: np.ndarray, explained: np.ndarray) -> np.ndarray:
        """Feed one frame: ``image_bgr`` (h, w, 3) uint8, ``foreground`` (h, w) the raw silhouette
        (non-zero = foreground, clutter included), ``explained`` (h, w) bool, the pixels the fitted
        body covers (grown by the caller's margin).  Returns ``mask``.

        Counts up where foreground, unexplained and unchanged since the last fed frame; holds
        where the body covers the pixel (a limb passing in front of the chair); restarts
        elsewhere.  Clutter that is background again is dropped at once."""
        fg = np.asarray(foreground) > 0
        expl = np.asarray(explained, dtype=bool)
        if fg.shape != self._count.shape or expl.shape != fg.shape:
            raise ClutterError(f"foreground, explained: expected shape {self._count.shape}, got {fg.shape}, {expl.shape}")
        img = check_image_bgr(image_bgr, "image_bgr", size=self.size)
        # outside the foreground everything restarts: work in the box of this frame's foreground
        # and the last one's (the state is zero outside the last box)
        x, y, w, h = cv2.boundingRect(fg.view(np.uint8))
        box = (x, y, x + w, y + h) if w and h else None
        last, self._box = self._box, box
        if last is not None and box is not None:
            box = (min(box[0], last[0]), min(box[1], last[1]), max(box[2], last[2]), max(box[3], last[3]))
        elif box is None:
            box = last
        if box is not None:
            sl = np.s_[box[1]:box[3], box[0]:box[2]]
            f, e = fg[sl], expl[sl]
            if self._last is None:
                steady = np.ones_like(f)
            else:
                diff = cv2.absdiff(img[sl], self._last[sl])
                steady = cv2.transform(diff, np.ones((1, 3), np.float32)).reshape(f.shape) <= self.colour_tol
            count = self._count[sl]
            count[:] = np.where(f & ~e & steady, np.minimum(count, np.uint16(60000)) + np.uint16(1),
                                np.where(f & e, count, np.uint16(0)))
            self.mask[sl] = (count >= self.learn_frames) | (self.mask[sl] & f)
        self._last = img.copy()
        self.frames += 1
        return self.mask

    def reset(self) -> None:
        """Forget everything learned."""
        self._count[:] = 0
        self.mask[:] = False
        self._last = None
        self._box = None
        self.frames = 0


def without_clutter(silhouette: np.ndarray, clutter: np.ndarray | None, *, keep: np.ndarray | None = None,
                    min_area_px: float = 0.0) -> np.ndarray:
    """``silhouette`` (h, w) uint8 0/255 with the ``clutter`` pixels (bool, same shape) removed,
    except those in ``keep`` (bool: the body's current projection), and the components left
    smaller than ``min_area_px`` dropped.  Returns a new 0/255 uint8 array (``silhouette``
    itself when there is no clutter)."""
    if clutter is None or not clutter.any():
        return silhouette
    cut = clutter if keep is None else (clutter & ~keep)
    out = np.where(cut, 0, silhouette).astype(np.uint8)
    if min_area_px > 0:
        n, labels, stats, _ = cv2.connectedComponentsWithStats(out, connectivity=8)
        small = np.flatnonzero(stats[:, cv2.CC_STAT_AREA] < min_area_px)
        small = small[small > 0]
        if small.size:
            out[np.isin(labels, small)] = 0
    return out


def segment_without_clutter(model: BackgroundModel, image_bgr: np.ndarray, clutter: np.ndarray | None, *,
                            keep: np.ndarray | None = None, ignore: np.ndarray | None = None,
                            params: SegmentationParams | None = None,
                            floor=None) -> tuple[FrameSegmentation, np.ndarray]:
    """``segmentation.pipeline.segment_frame`` with the clutter cut (``without_clutter``) between
    the silhouette and the edges / chamfer images; ``ignore`` (h, w) bool is cut whatever ``keep``
    says (the operator's never-body pixels).  Returns ``(segmentation of the body, raw silhouette
    (h, w) uint8 with the clutter, ignore regions cut)``; the raw one feeds ``StaticClutter.update``;
    ``floor``: the floor test, as ``segment_frame``'s."""
    params = params or SegmentationParams()
    w, h = model.size
    raw = np.zeros((h, w), np.uint8)

    def cut(sil_roi: np.ndarray, box) -> np.ndarray:
        x0, y0, x1, y1 = box
        if ignore is not None:
            sil_roi = np.where(ignore[y0:y1, x0:x1], 0, sil_roi).astype(np.uint8)
        raw[y0:y1, x0:x1] = sil_roi
        if clutter is None:
            return sil_roi
        return without_clutter(sil_roi, clutter[y0:y1, x0:x1], keep=None if keep is None else keep[y0:y1, x0:x1],
                               min_area_px=0.25 * params.min_area_px((w, h)))

    return segment_frame(model, image_bgr, params=params, cut=cut, floor=floor), raw


def ignore_masks(sizes: Mapping[str, tuple[int, int]], regions: Mapping[str, Sequence[Sequence[int]]]) -> dict:
    """``ignore_mask`` per camera name for the cameras of ``sizes`` that have regions."""
    unknown = sorted(set(regions) - set(sizes))
    if unknown:
        raise ClutterError(f"ignore regions for unknown camera(s) {unknown} (have {sorted(sizes)})")
    return {n: ignore_mask(sizes[n], regs) for n, regs in regions.items() if regs}


def session_ignore_regions(session_toml) -> dict[str, list[tuple[int, int, int, int]]]:
    """The ``ignore = [[x, y, w, h], ...]`` lists of the ``[[camera]]`` tables of a session.toml
    (camera name -> rectangles; cameras without one are left out).  ValueError on a bad entry."""
    import tomllib
    from pathlib import Path

    path = Path(session_toml)
    with open(path, "rb") as fh:
        data = tomllib.load(fh)
    out: dict[str, list] = {}
    for table in data.get("camera", []):
        regs = table.get("ignore") if isinstance(table, dict) else None
        if regs is None:
            continue
        name = table.get("name")
        if not isinstance(regs, list) or not all(isinstance(r, list) and len(r) == 4 and
                                                 all(isinstance(v, int) and not isinstance(v, bool) for v in r)
                                                 for r in regs):
            raise ClutterError(f"{path} camera {name!r} key 'ignore': expected a list of [x, y, w, h] whole pixels")
        if any(r[2] <= 0 or r[3] <= 0 for r in regs):
            raise ClutterError(f"{path} camera {name!r} key 'ignore': width and height must be > 0")
        out[str(name)] = [tuple(r) for r in regs]
    return out
