"""Calibration boards: checkerboard geometry, automatic detection, corners from a user's outline.

Board frame
-----------
A checkerboard has ``cols × rows`` *inner* corners (OpenCV's ``patternSize``;
uu_studio: 8 × 6 with 115 mm squares, i.e. 9 × 7 squares).  Corner ``(i, j)``,
``i`` in ``[0, cols)`` along the side with more corners, ``j`` in
``[0, rows)``, is stored at index ``j * cols + i`` and lies at
``(i * s, j * s, 0)`` in board coordinates (metres).  Which physical corner is
``(0, 0)`` is chosen by the caller (an *origin hint* pixel, or the first
corner of a user's outline): a plain checkerboard is symmetric under a
half turn, so nothing in the image can decide it.

User outline
------------
Where no detector finds the board (small, grazing views), the user gives the
board's four **outer pattern corners** (the outer vertices of the four corner
squares) in the order: origin corner, the next corner along the long side
(``cols``), the opposite corner, the corner along the short side.
``corners_from_outline`` maps a rendered board template onto the undistorted
image with that homography and refines it with ECC image alignment
(``cv2.findTransformECC``, homography motion) over all the board's pixels,
which stays accurate where squares are only a few pixels tall; the inner
corners are then mapped through the refined homography and re-distorted.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from capture.calib_formats import open_storage

__all__ = [
    "Checkerboard",
    "CharucoBoard",
    "detect_board",
    "OutlineCorners",
    "detect_checkerboard",
    "corners_from_outline",
    "relabel_to_origin",
    "undistort_pixels",
    "distort_pixels",
]


@dataclass(frozen=True)
class Checkerboard:
    """A checkerboard: ``cols × rows`` inner corners, ``square_m`` metres per square (cols >= rows)."""

    cols: int
    rows: int
    square_m: float

    def __post_init__(self):
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"board needs at least 2 × 2 inner corners, got {self.cols} × {self.rows}")
        if self.cols < self.rows:
            raise ValueError(f"board: give the long side first (cols >= rows), got {self.cols} × {self.rows}")
        if not self.square_m > 0:
            raise ValueError(f"board square size must be positive metres, got {self.square_m}")

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows

    @property
    def pattern_size(self) -> tuple[int, int]:
        return self.cols, self.rows

    def grid(self) -> np.ndarray:
        """Integer corner coordinates ``(i, j)``, shape (n_corners, 2), index ``j * cols + i``."""
        i, j = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.stack([i.ravel(), j.ravel()], axis=-1)

    def object_points(self, *, swap_axes: bool = False) -> np.ndarray:
        """Board-frame corners (metres), shape (n_corners, 3), z = 0.

        ``swap_axes`` puts ``i`` on y and ``j`` on x: the other handedness,
        used so that the board normal (z) points towards the cameras.
        """
        g = self.grid().astype(float) * self.square_m
        if swap_axes:
            g = g[:, ::-1]
        return np.c_[g, np.zeros(len(g))]

    @classmethod
    def from_opencv_xml(cls, path) -> "Checkerboard":
        """Read ``CheckerBoardWidth``/``Height`` (inner corners) and ``CheckerBoardSquareSize`` (mm)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: board file not found")
        fs = open_storage(path, what="board file")
        vals = {}
        for key in ("CheckerBoardWidth", "CheckerBoardHeight", "CheckerBoardSquareSize"):
            node = fs.getNode(key)
            if node.empty():
                raise ValueError(f"{path} [root]: missing key {key!r}")
            if not (node.isInt() or node.isReal()) or not np.isfinite(node.real()) or node.real() <= 0:
                raise ValueError(f"{path} [root]: key {key!r} must be a positive number")  # real() of text is junk
            vals[key] = node.real()
        w, h = vals["CheckerBoardWidth"], vals["CheckerBoardHeight"]
        if w != int(w) or h != int(h):
            raise ValueError(f"{path} [root]: CheckerBoardWidth/Height must be whole numbers of inner corners")
        w, h = int(w), int(h)
        try:
            return cls(max(w, h), min(w, h), vals["CheckerBoardSquareSize"] / 1000.0)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board: ``squares_x × squares_y`` squares, ``square_m``/``marker_m`` metres, an ArUco dictionary name."""

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self):
        if self.squares_x < 3 or self.squares_y < 3:
            raise ValueError(f"ChArUco board needs at least 3 × 3 squares, got {self.squares_x} × {self.squares_y}")
        if not 0 < self.marker_m < self.square_m:
            raise ValueError(f"ChArUco marker size must be in (0, square size), got {self.marker_m} vs {self.square_m}")
        if not hasattr(cv2.aruco, self.dictionary):
            raise ValueError(f"unknown ArUco dictionary {self.dictionary!r} (e.g. DICT_4X4_50, DICT_5X5_100)")

    def cv_board(self):
        """The ``cv2.aruco.CharucoBoard``."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)

    def object_points(self) -> np.ndarray:
        """Board-frame inner corners (metres), shape ((squares_x-1)(squares_y-1), 3), indexed by ChArUco id."""
        return np.asarray(self.cv_board().getChessboardCorners(), dtype=float).reshape(-1, 3)


def detect_board(gray: np.ndarray, board, *, min_corners: int = 6) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners of a ``Checkerboard`` or ``CharucoBoard`` in one image.

    Returns ``(image_points (n, 2) raw pixels, object_points (n, 3) board frame)``
    or ``None``.  A ChArUco board may be partly visible (``n >= min_corners``).
    """
    if isinstance(board, Checkerboard):
        c = detect_checkerboard(gray, board)
        return None if c is None else (c, board.object_points())
    if isinstance(board, CharucoBoard):
        detector = cv2.aruco.CharucoDetector(board.cv_board())
        corners, ids, _, _ = detector.detectBoard(gray)
        if ids is None or len(ids) < min_corners:
            return None
        return np.asarray(corners, dtype=float).reshape(-1, 2), board.object_points()[np.asarray(ids).ravel()]
    raise TypeError(f"unsupported board type {type(board).__name__}")


@dataclass(frozen=True)
class OutlineCorners:
    """Inner corners found from a user outline.

    corners : ndarray, shape (n_corners, 2)
        Raw (distorted) pixel coordinates, board index order.
    correlation : float
        ECC correlation of the aligned template (1 = perfect; < 0.5 is suspect).
    moved_px : float
        Largest distance an outline corner moved during refinement (a sanity figure for the user's clicks).
    """

    corners: np.ndarray
    correlation: float
    moved_px: float


def detect_checkerboard(gray: np.ndarray, board: Checkerboard) -> np.ndarray | None:
    """Find the inner corners automatically, or ``None``.

    Tries ``findChessboardCornersSB`` (exhaustive + accuracy) then the classic
    detector, whose corners are refined with ``cornerSubPix`` (window sized
    from the corner spacing).  SB's own sub-pixel corners are kept (refining
    them again made the board fit worse: docs/tuning.md).  Returns raw pixel coordinates,
    shape (n_corners, 2), in OpenCV's order (``cols`` per row, origin at
    whichever corner the detector picked: see ``relabel_to_origin``).
    """
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    ok, c = cv2.findChessboardCornersSB(gray, board.pattern_size, flags=flags)
    if ok:
        return np.asarray(c, dtype=float).reshape(-1, 2)
    ok, c = cv2.findChessboardCorners(gray, board.pattern_size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
    if not ok:
        return None
    c = np.asarray(c, dtype=np.float32).reshape(-1, 2)
    # cornerSubPix with a window under ~1/3 of the shortest corner spacing (grazing views have short squares)
    g = c.reshape(board.rows, board.cols, 2)
    spacing = min(np.linalg.norm(np.diff(g, axis=0), axis=-1).min(), np.linalg.norm(np.diff(g, axis=1), axis=-1).min())
    half = int(np.clip(spacing / 3.0, 1, 5))
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    return cv2.cornerSubPix(gray, c.reshape(-1, 1, 2).copy(), (half, half), (-1, -1), crit).reshape(-1, 2).astype(float)


def relabel_to_origin(corners: np.ndarray, board: Checkerboard, origin_px) -> np.ndarray:
    """Reorder detected corners (n_corners, 2) so that the grid corner nearest ``origin_px`` is index 0.

    The ``i`` direction stays along the long side; of the four extreme corners
    the nearest to ``origin_px`` (pixel, raw image) becomes ``(0, 0)``.
    """
    grid = np.asarray(corners, dtype=float).reshape(board.rows, board.cols, 2)
    options = [grid, grid[:, ::-1], grid[::-1, :], grid[::-1, ::-1]]
    dist = [np.linalg.norm(g[0, 0] - np.asarray(origin_px, dtype=float)) for g in options]
    return options[int(np.argmin(dist))].reshape(-1, 2).copy()


def undistort_pixels(uv: np.ndarray, matrix: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    """Raw pixels (n, 2) -> ideal pinhole pixels (n, 2) under the same ``matrix``."""
    pts = np.asarray(uv, dtype=np.float64).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
    return cv2.undistortPoints(pts, matrix, distortion, None, None, matrix, crit).reshape(-1, 2)


def distort_pixels(uv: np.ndarray, matrix: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    """Ideal pinhole pixels (n, 2) -> raw (distorted) pixels (n, 2)."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    xy = (uv - matrix[:2, 2]) @ np.linalg.inv(matrix[:2, :2]).T
    rays = np.c_[xy, np.ones(len(xy))]
    out, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), matrix, distortion)
    return out.reshape(-1, 2)


def _apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    h = np.c_[pts, np.ones(len(pts))] @ H.T
    return h[:, :2] / h[:, 2:]


def _template(board: Checkerboard, pps: float, border: float) -> np.ndarray:
    """Rendered board (float32, 0 black / 255 white) with ``pps`` pixels per square and a white ``border`` (squares)."""
    w = int(round((board.cols + 1 + 2 * border) * pps))
    h = int(round((board.rows + 1 + 2 * border) * pps))
    x = (np.arange(w) + 0.5) / pps - (1 + border)
    y = (np.arange(h) + 0.5) / pps - (1 + border)
    X, Y = np.meshgrid(x, y)
    inside = (X > -1) & (X < board.cols) & (Y > -1) & (Y < board.rows)
    black = (np.floor(X) + np.floor(Y)) % 2 == 0  # corner squares are black
    return np.where(inside & black, 0.0, 255.0).astype(np.float32)


def corners_from_outline(
    gray: np.ndarray,
    board: Checkerboard,
    outline_px,
    *,
    matrix: np.ndarray,
    distortion: np.ndarray,
    pixels_per_square: float = 12.0,
    border_squares: float = 0.5,
    starts: int = 8,
    jitter_px: float = 5.0,
    blur_sizes: tuple[int, ...] = (5,),
) -> OutlineCorners:
    """Inner corners from the four outer pattern corners a user gave (see module doc).

    Parameters
    ----------
    gray : ndarray, shape (h, w)
        Raw image (averaging a few frames of a static board reduces noise).
    outline_px : array, shape (4, 2)
        Raw pixels: origin, along the long side, opposite, along the short side.
    matrix, distortion : the camera's intrinsics (K (3, 3), OpenCV distortion (5,)).
    starts, jitter_px, blur_sizes :
        ECC is run (with Gaussian ``blur_sizes`` in turn) from the outline and
        from ``starts - 1`` copies of it with every corner moved by up to
        ``jitter_px`` (seeded, so results are repeatable); the alignment with
        the highest correlation wins.  On small grazing boards ECC has local
        optima 2-3 px apart: on uu_studio cam1/cam4 a single start from clicks
        4 px off lands in a wrong one about half the time; with these defaults
        7 of 7 perturbed outlines reached the same best one, which is the one
        whose corners sit on the X-junctions and (cam1) that puts cam3 where
        cam1 sees it.
    """
    outline = np.asarray(outline_px, dtype=float)
    if outline.shape != (4, 2) or not np.all(np.isfinite(outline)):
        raise ValueError(f"outline must be 4 finite (x, y) pixel corners, got shape {outline.shape}")
    matrix = np.asarray(matrix, dtype=float)
    distortion = np.asarray(distortion, dtype=float)
    und = cv2.undistort(np.asarray(gray, dtype=np.float32), matrix, distortion)
    outline_u = undistort_pixels(outline, matrix, distortion)

    def tpl(bx, by):  # board coordinates (squares) -> template pixel coordinates (pixel centres at integers)
        return np.stack([(np.asarray(bx) + 1 + border_squares) * pixels_per_square - 0.5,
                         (np.asarray(by) + 1 + border_squares) * pixels_per_square - 0.5], axis=-1)

    template = _template(board, pixels_per_square, border_squares)
    tpl_outline = tpl([-1, board.cols, board.cols, -1], [-1, -1, board.rows, board.rows]).astype(np.float32)
    jitter = np.random.default_rng(0).uniform(-jitter_px, jitter_px, (max(starts, 1), 4, 2))
    jitter[0] = 0.0
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-5)
    best, errors = None, []
    for shift in jitter:
        H = cv2.getPerspectiveTransform(tpl_outline, (outline_u + shift).astype(np.float32))
        try:
            for size in blur_sizes:
                cc, H = cv2.findTransformECC(template, und, H.astype(np.float32), cv2.MOTION_HOMOGRAPHY, crit, None, size)
        except cv2.error as exc:
            errors.append(str(exc).splitlines()[-1])
            continue
        if best is None or cc > best[0]:
            best = (float(cc), H.astype(float))
    if best is None:
        raise ValueError(f"could not align the board to the outline (ECC did not converge): {errors[0]}")
    cc, H = best
    grid = board.grid()
    inner_u = _apply_h(H, tpl(grid[:, 0], grid[:, 1]))
    moved = float(np.linalg.norm(_apply_h(H, tpl_outline) - outline_u, axis=1).max())
    return OutlineCorners(distort_pixels(inner_u, matrix, distortion), cc, moved)
