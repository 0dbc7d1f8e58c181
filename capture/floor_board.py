"""Extrinsics from a board lying on the floor, filmed by every camera (static board, a few frames each).

Per camera: sample a few frames of its board video; detect the inner corners
(``capture.board.detect_checkerboard``) and take the per-corner median over
the frames where it was found; where it is never found and the user gave the
board's outline (four outer pattern corners), recover the corners from the
outline on the mean of the frames (``corners_from_outline``); otherwise the
camera is reported as failed, with the reason.

Origin: the board corner ``(0, 0)`` nearest each camera's *origin hint*
pixel (the first outline corner doubles as one).  A camera with neither keeps
the detector's choice, which is reported, because a checkerboard is
symmetric under a half turn.  Handedness: the board axes are assigned so
that the cameras are above the floor (z > 0); a camera that would land below
while the others are above used the wrong origin corner and is reported.

Corner file (TOML), raw pixel coordinates::

    [cam1]
    corners = [[x0, y0], [x1, y1], [x2, y2], [x3, y3]]  # origin, long side, opposite, short side
    [cam2]
    origin = [x, y]                                      # origin hint only
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import cv2
import numpy as np

from capture.board import Checkerboard, corners_from_outline, detect_checkerboard, relabel_to_origin
from capture.calibrate import (
    BoardObservation,
    ExtrinsicsResult,
    Intrinsics,
    Progress,
    solve_board_pose,
    calibrate_extrinsics,
)
from capture.camera import rodrigues_to_matrix
from capture.tomlio import load_file

__all__ = ["FloorView", "read_board_frames", "floor_view", "load_corner_file", "calibrate_floor", "FloorCalibration"]

_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


@dataclass(frozen=True)
class FloorView:
    """The floor board in one camera: ``corners`` (n, 2) raw pixels in board order, or ``None`` with ``reason``."""

    camera: str
    corners: np.ndarray | None
    method: str = ""
    frames: tuple[int, ...] = ()
    note: str = ""
    reason: str = ""


@dataclass(frozen=True)
class FloorCalibration:
    """``calibrate_floor`` output: the bundle-adjusted extrinsics, each camera's floor view, and the axis choice."""

    extrinsics: ExtrinsicsResult
    views: tuple[FloorView, ...]
    swap_axes: bool


def read_board_frames(path, *, n_frames: int = 3) -> tuple[list[np.ndarray], list[int]]:
    """Up to ``n_frames`` grey frames (h, w) uint8 spread evenly over a video (or one image file), and their indices."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: board video/image not found")
    if path.suffix.lower() in _IMAGE_SUFFIXES:
        img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise ValueError(f"{path}: unreadable image")
        return [img], [0]
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise ValueError(f"{path}: unreadable video")
    count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    wanted = set(np.linspace(0, max(count - 1, 0), max(1, n_frames)).round().astype(int).tolist()) if count > 0 else None
    grey, ids, k, last = [], [], 0, None

    def keep(index, image):
        grey.append(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image)
        ids.append(index)

    while True:
        ok, frame = cap.read()
        if not ok:
            break
        if wanted is None or k in wanted:
            keep(k, frame)
        last = (k, frame)
        k += 1
    cap.release()
    if last is None:
        raise ValueError(f"{path}: video has no readable frames")
    if wanted is not None and len(ids) < len(wanted) and ids[-1:] != [last[0]]:
        keep(*last)  # the container over-stated its frame count: use the last frame that decoded
    if wanted is None and len(grey) > n_frames:  # frame count unknown: thin out afterwards
        keep = np.unique(np.linspace(0, len(grey) - 1, n_frames).round().astype(int))
        grey, ids = [grey[i] for i in keep], [ids[i] for i in keep]
    return grey, ids


def floor_view(
    name: str,
    frames: Sequence[np.ndarray],
    frame_ids: Sequence[int],
    intr: Intrinsics,
    board: Checkerboard,
    *,
    outline=None,
    origin_hint=None,
) -> FloorView:
    """Board corners in one camera from a few frames of a static board (see module doc).

    Parameters
    ----------
    name : str
        Camera name.
    frames : sequence of ndarray, shape (h, w), uint8
        Grey frames of the static board.
    frame_ids : sequence of int
        Their frame indices (reported in ``FloorView.frames``).
    intr : Intrinsics
    board : Checkerboard
    outline : array_like, shape (4, 2), optional
        The user's four outer pattern corners (pixels), for views where detection fails.
    origin_hint : array_like, shape (2,), optional
        Pixel near the board corner that is the world origin.

    Returns
    -------
    FloorView
        Corners (n, 2) raw pixels in board order, or None with the reason.
    """
    hint = origin_hint if origin_hint is not None else (None if outline is None else np.asarray(outline)[0])
    found, used = [], []
    for n, (f, k) in enumerate(zip(frames, frame_ids)):
        if n >= 1 and not found:
            break  # the board is static: if the first frame does not show it, its near-copies will not either
        c = detect_checkerboard(f, board)
        if c is not None:
            ref = hint if hint is not None else (found[0][0] if found else c[0])
            found.append(relabel_to_origin(c, board, ref))
            used.append(k)
    if found:
        note = "origin from hint" if hint is not None else "origin corner chosen by the detector (no hint given)"
        return FloorView(name, np.median(np.stack(found), axis=0), "detected", tuple(used), note)
    if outline is None:
        return FloorView(name, None, reason=(
            "board not found by findChessboardCornersSB or findChessboardCorners (static board: one frame tried); "
            "give its four outer corners (--corners)"))
    mean = np.mean(np.stack([f.astype(np.float32) for f in frames]), axis=0)
    try:
        oc = corners_from_outline(mean, board, outline, matrix=intr.matrix, distortion=intr.distortion)
    except ValueError as exc:
        return FloorView(name, None, reason=f"manual corners: {exc}")
    if oc.correlation < 0.5:
        return FloorView(name, None, reason=(
            f"manual corners: the board template matches the image poorly (ECC correlation {oc.correlation:.2f}); "
            "check the order: origin, along the long side, opposite, along the short side"))
    note = f"manual outline refined by ECC (correlation {oc.correlation:.2f}, outline moved {oc.moved_px:.1f} px)"
    return FloorView(name, oc.corners, "manual", tuple(frame_ids), note)


def _parse_point_list(value, where: str, n: int) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: not a list of numbers") from None
    if arr.shape != (n, 2):
        raise ValueError(f"{where}: expected {n} (x, y) pixel pairs, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: pixel coordinates must be finite numbers, got {arr.tolist()}")
    return arr


def load_corner_file(path) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Read a corner file (module doc) -> (outlines {camera: (4, 2)}, origin hints {camera: (2,)})."""
    path = Path(path)
    try:
        data = load_file(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: corner file not found") from None
    outlines, hints = {}, {}
    for cam, table in data.items():
        if not isinstance(table, dict):
            raise ValueError(f"{path}: top-level key {cam!r} must be a [camera] table")
        if "corners" in table:
            outlines[cam] = _parse_point_list(table["corners"], f"{path} [{cam}] key 'corners'", 4)
        if "origin" in table:
            hints[cam] = _parse_point_list([table["origin"]], f"{path} [{cam}] key 'origin'", 1)[0]
        if "corners" not in table and "origin" not in table:
            raise ValueError(f"{path} [{cam}]: needs key 'corners' (4 outer corners) or 'origin' (hint)")
    return outlines, hints


def _camera_height(obs: BoardObservation, intr: Intrinsics) -> float:
    rv, tv = solve_board_pose(obs, intr)
    return float((-rodrigues_to_matrix(rv).T @ tv)[2])


def calibrate_floor(
    intrinsics: Sequence[Intrinsics],
    videos: Mapping[str, Path],
    board: Checkerboard,
    *,
    outlines: Mapping[str, np.ndarray] | None = None,
    origin_hints: Mapping[str, np.ndarray] | None = None,
    n_frames: int = 3,
    progress: Progress | None = None,
) -> FloorCalibration:
    """Extrinsics of every camera from its video of the board lying on the floor (see module doc).

    Parameters
    ----------
    intrinsics : sequence of Intrinsics
        One per camera (their names are the camera names).
    videos : mapping
        Camera name -> video (or image) of the board on the floor.
    board : Checkerboard
    outlines, origin_hints : mapping, optional
        Camera name -> outline (4, 2) / origin hint (2,) in pixels (see :func:`floor_view`).
    n_frames : int
        Frames read per video.
    progress : Progress, optional

    Returns
    -------
    FloorCalibration
    """
    if n_frames < 1:
        raise ValueError(f"n_frames: need at least 1 frame per video, got {n_frames}")
    outlines, origin_hints = dict(outlines or {}), dict(origin_hints or {})
    names = [i.name for i in intrinsics]
    for key in list(outlines) + list(origin_hints) + list(videos):
        if key not in names:
            raise ValueError(f"camera {key!r} (corners/origin/video) is not one of the cameras {names}")
    intr = {i.name: i for i in intrinsics}
    views = []
    for k, name in enumerate(names):
        if progress:
            progress(k, len(names) + 1, f"board in {name}")
        if name not in videos:
            views.append(FloorView(name, None, reason="no board video given"))
            continue
        frames, ids = read_board_frames(videos[name], n_frames=n_frames)
        views.append(floor_view(name, frames, ids, intr[name], board,
                                outline=outlines.get(name), origin_hint=origin_hints.get(name)))
    failures = {v.camera: v.reason for v in views if v.corners is None}
    plain = {v.camera: BoardObservation(v.camera, 0, v.corners, board.object_points(), v.method, v.frames)
             for v in views if v.corners is not None}
    heights = {n: _camera_height(o, intr[n]) for n, o in plain.items()}
    swap = sum(h < 0 for h in heights.values()) > len(heights) / 2
    obs = []
    for n, o in plain.items():
        if (heights[n] < 0) != swap:
            failures[n] = ("board origin corner inconsistent with the other cameras (this camera would be below "
                           "the floor): check its origin hint / corner order")
            continue
        obs.append(BoardObservation(n, 0, o.image_points, board.object_points(swap_axes=swap), o.method, o.frames))
    result = calibrate_extrinsics(intrinsics, obs, failures=failures,
                                  progress=(lambda i, n, msg: progress(len(names), len(names) + 1, msg)) if progress else None)
    if progress:
        progress(len(names) + 1, len(names) + 1, "done")
    return FloorCalibration(result, tuple(views), swap)
