"""Drawing helpers for reviewing a fit over camera images: arrays in, images out (no files).

Used by ``service.review`` (``contourcap review``).  Colours are BGR (OpenCV order).  Left parts
(names starting ``left``) are drawn in ``LEFT``, right parts in ``RIGHT``, the rest (pelvis, spine,
head) in ``CENTRE``.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import cv2
import numpy as np

__all__ = ["LEFT", "RIGHT", "CENTRE", "SKELETON", "side_of", "side_colours", "draw_contours",
           "draw_skeleton", "draw_text", "tile_images", "resize_to_width"]

LEFT: tuple[int, int, int] = (255, 150, 0)     # blue
RIGHT: tuple[int, int, int] = (0, 80, 255)     # orange-red
CENTRE: tuple[int, int, int] = (0, 230, 0)     # green
_SIDES = np.array([CENTRE, LEFT, RIGHT], dtype=np.uint8)

# bones between the pose record's joints (DESIGN.md joint names)
SKELETON: tuple[tuple[str, str], ...] = (
    ("pelvis", "spine"), ("spine", "neck"), ("neck", "head"),
    ("neck", "left_shoulder"), ("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
    ("neck", "right_shoulder"), ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"),
    ("pelvis", "left_hip"), ("left_hip", "left_knee"), ("left_knee", "left_ankle"),
    ("pelvis", "right_hip"), ("right_hip", "right_knee"), ("right_knee", "right_ankle"),
)


def side_of(name: str) -> int:
    """0 centre, 1 left, 2 right, from a part or joint name."""
    return 1 if name.startswith("left") else 2 if name.startswith("right") else 0


def side_colours(names: Sequence[str]) -> np.ndarray:
    """BGR colour (n, 3) uint8 of each part / joint name by its side."""
    return _SIDES[[side_of(n) for n in names]]


def draw_contours(image: np.ndarray, uv: np.ndarray, visible: np.ndarray, colours: np.ndarray, *,
                  thickness: int = 2) -> np.ndarray:
    """Draw contour rulings as polylines on ``image`` (in place) and return it.

    Parameters
    ----------
    image : ndarray, shape (h, w, 3), uint8
    uv : ndarray, shape (r, s, 2)
        Pixel coordinates of ``s`` samples along each of ``r`` rulings (one side of one part).
    visible : ndarray of bool, shape (r, s)
        Samples to draw; a segment is drawn between two consecutive visible samples.
    colours : ndarray, shape (r, 3)
        BGR colour of each ruling.
    thickness : int
        Line width in pixels.
    """
    uv = np.asarray(uv, dtype=float)
    vis = np.asarray(visible, dtype=bool)
    seg = vis[:, 1:] & vis[:, :-1]  # (r, s-1)
    r_idx, s_idx = np.nonzero(seg)
    if len(r_idx):
        a = np.round(uv[r_idx, s_idx]).astype(np.int32)
        b = np.round(uv[r_idx, s_idx + 1]).astype(np.int32)
        lines = np.stack([a, b], axis=1)  # (m, 2, 2)
        cols = np.asarray(colours)[r_idx]
        for c in np.unique(cols, axis=0):  # one polylines call per colour
            pick = np.all(cols == c, axis=1)
            cv2.polylines(image, list(lines[pick]), False, tuple(int(v) for v in c), thickness, cv2.LINE_AA)
    lone = vis & ~np.concatenate([seg, np.zeros((len(vis), 1), bool)], axis=1) \
        & ~np.concatenate([np.zeros((len(vis), 1), bool), seg], axis=1)
    for r, s in zip(*np.nonzero(lone)):  # isolated visible samples (rare): a dot
        cv2.circle(image, tuple(int(v) for v in np.round(uv[r, s])), thickness, tuple(int(v) for v in colours[r]), -1)
    return image


def draw_skeleton(image: np.ndarray, joints_uv: Mapping[str, np.ndarray], *, names: bool = False,
                  bones: Sequence[tuple[str, str]] = SKELETON, radius: int = 3) -> np.ndarray:
    """Draw bones (white lines) and joints (dots by side, optionally named) on ``image`` in place.

    ``joints_uv``: joint name -> pixel (2,) (joints not in it, or non-finite, are skipped).
    """
    pts = {n: tuple(int(v) for v in np.round(p)) for n, p in joints_uv.items()
           if np.all(np.isfinite(p)) and np.all(np.abs(p) < 1e5)}
    for a, b in bones:
        if a in pts and b in pts:
            cv2.line(image, pts[a], pts[b], (255, 255, 255), 1, cv2.LINE_AA)
    for n, p in pts.items():
        cv2.circle(image, p, radius, tuple(int(v) for v in _SIDES[side_of(n)]), -1, cv2.LINE_AA)
        if names:
            cv2.putText(image, n, (p[0] + 4, p[1] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (255, 255, 255), 1,
                        cv2.LINE_AA)
    return image


def draw_text(image: np.ndarray, lines: Sequence[str], *, colour=(255, 255, 255), origin=(6, 6),
              scale: float = 0.5) -> np.ndarray:
    """Lines of text on a dark band at ``origin`` (top-left, pixels), in place."""
    if not lines:
        return image
    (w, h), base = cv2.getTextSize("Mg", cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    step = h + base + 4
    width = max(cv2.getTextSize(t, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0] for t in lines)
    x0, y0 = origin
    x1, y1 = min(image.shape[1], x0 + width + 8), min(image.shape[0], y0 + step * len(lines) + 4)
    band = image[y0:y1, x0:x1]
    band[:] = (band.astype(np.uint16) * 2 // 5).astype(np.uint8)  # darken behind the text
    for i, t in enumerate(lines):
        cv2.putText(image, t, (x0 + 4, y0 + (i + 1) * step - base), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    tuple(int(v) for v in colour), 1, cv2.LINE_AA)
    return image


def tile_images(images: Sequence[np.ndarray], cols: int | None = None) -> np.ndarray:
    """Images of one size (h, w, 3) in a grid (``cols`` columns, default ceil(sqrt(n))), black padding."""
    if not images:
        raise ValueError("tile_images: no image")
    h, w = images[0].shape[:2]
    if any(im.shape[:2] != (h, w) for im in images):
        raise ValueError("tile_images: images differ in size")
    n = len(images)
    cols = int(np.ceil(np.sqrt(n))) if cols is None else max(1, int(cols))
    rows = -(-n // cols)
    out = np.zeros((rows * h, cols * w, 3), np.uint8)
    for i, im in enumerate(images):
        r, c = divmod(i, cols)
        out[r * h:(r + 1) * h, c * w:(c + 1) * w] = im
    return out


def resize_to_width(image: np.ndarray, width: int, *, even: bool = False) -> np.ndarray:
    """``image`` scaled (down only) to at most ``width`` pixels wide; ``even``: both sides made even
    (what most video codecs need) by cropping at most one row/column."""
    if image.shape[1] > width:
        s = width / image.shape[1]
        image = cv2.resize(image, (width, max(1, int(round(image.shape[0] * s)))), interpolation=cv2.INTER_AREA)
    if even:
        image = image[: image.shape[0] // 2 * 2, : image.shape[1] // 2 * 2]
    return image
