"""Import the uu_studio recording (Utrecht University vision course; ../shared/data/uu_studio) as a session.

Source layout::

    SRC/checkerboard.xml          CheckerBoardWidth/Height (inner corners), CheckerBoardSquareSize (mm)
    SRC/camN/config.xml           OpenCV intrinsics (good) and extrinsics (wrong in scale: not used)
    SRC/camN/checkerboard.avi     the board lying on the floor (static)
    SRC/camN/background.avi       the empty room
    SRC/camN/video.avi            the take

Result: a session directory (DESIGN.md) with ``calibration.toml`` computed
here from the floor checkerboard (``capture.floor_board.calibrate_floor``:
world origin at a board corner, Z up, metres), ``camN.avi`` and
``background/camN.avi`` symlinked (or copied) from the source, and
``session.toml`` written by ``capture.session.write_session_toml``.

The board is not found automatically in cam1 and cam4 (small, grazing
views); their outlines (user input, read off the frames) ship in
``uu_studio_corners.toml`` next to this module, with origin hints for cam2
and cam3 so that all four cameras agree on the board corner that is the
origin (the one the recording's own config.xml used).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2

from capture.board import Checkerboard
from capture.calib_formats import read_opencv_camera
from capture.calibrate import Intrinsics, Progress
from capture.calibration import save_calibration
from capture.camera import Camera
from capture.errors import CaptureError
from capture.floor_board import FloorCalibration, calibrate_floor, load_corner_file
from capture.session import CALIBRATION_FILE, write_session_toml

__all__ = ["CORNERS_FILE", "UU_CAMERAS", "UUImportError", "ImportResult", "import_uu_studio"]

CORNERS_FILE = Path(__file__).resolve().parent / "uu_studio_corners.toml"
UU_CAMERAS = ("cam1", "cam2", "cam3", "cam4")
_MEDIA = ("config.xml", "checkerboard.avi", "background.avi", "video.avi")


class UUImportError(CaptureError, ValueError):
    """The source folder or the calibration is unusable; the message names the file or camera."""


@dataclass(frozen=True)
class ImportResult:
    """Where the session went, its fps, decodable frames per camera video, and the calibration with its per-camera report."""

    session_dir: Path
    fps: float
    frame_counts: dict[str, int]
    cameras: tuple[Camera, ...]
    calibration: FloorCalibration


def _video_info(path: Path) -> tuple[float, int, tuple[int, int]]:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise UUImportError(f"{path}: unreadable video")
    fps = float(cap.get(cv2.CAP_PROP_FPS))
    ok, frame = cap.read()
    if not ok:
        cap.release()
        raise UUImportError(f"{path}: no readable frame")
    count = 1
    while cap.grab():  # count decodable frames: the container's own count can be too high
        count += 1
    cap.release()
    return fps, count, (int(frame.shape[1]), int(frame.shape[0]))


def _place(src: Path, dst: Path, copy: bool) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.is_symlink() or dst.exists():
        dst.unlink()
    if copy:
        shutil.copyfile(src, dst)
    else:
        dst.symlink_to(src.resolve())


def import_uu_studio(
    src,
    out,
    *,
    corners_file=CORNERS_FILE,
    copy: bool = False,
    name: str = "uu_studio",
    overwrite: bool = False,
    n_frames: int = 3,
    progress: Progress | None = None,
) -> ImportResult:
    """Convert the uu_studio folder ``src`` into the session directory ``out`` (see module doc).

    Parameters
    ----------
    src, out : path
        The uu_studio folder; the session directory written.
    corners_file : path
        Floor-board outlines and origin hints of the views where detection fails.
    copy : bool
        Copy the videos into ``out`` (else ``out`` holds symbolic links to them).
    name : str
        Session name.
    overwrite : bool
        Replace a session already in ``out``.
    n_frames : int
        Board frames read per floor video.
    progress : Progress, optional

    Returns
    -------
    ImportResult
        ``UUImportError`` names the missing file, or the camera that could not be calibrated
        and why; nothing is written before the calibration has succeeded.
    """
    src, out = Path(src), Path(out)
    board_file = src / "checkerboard.xml"
    for path in [board_file] + [src / c / m for c in UU_CAMERAS for m in _MEDIA]:
        if not path.is_file():
            raise UUImportError(f"{path}: missing (expected the uu_studio layout: checkerboard.xml, camN/{{{','.join(_MEDIA)}}})")
    if not isinstance(name, str) or not name:
        raise UUImportError(f"name: the session name must be a non-empty string, got {name!r}")
    if out.exists() and not out.is_dir():
        raise UUImportError(f"{out}: exists and is not a folder")
    if (out / "session.toml").exists() and not overwrite:
        raise UUImportError(f"{out}: already holds a session (session.toml); pass overwrite=True / --force to replace it")
    infos = {c: _video_info(src / c / "video.avi") for c in UU_CAMERAS}
    fps = {round(f, 3) for f, _, _ in infos.values()}
    if len(fps) != 1 or not next(iter(fps)) > 0:
        raise UUImportError(f"{src}: the cameras' video.avi files disagree on fps or state none: {sorted(fps)}")
    board = Checkerboard.from_opencv_xml(board_file)
    intr = [Intrinsics.from_camera(read_opencv_camera(src / c / "config.xml", name=c, size=infos[c][2])) for c in UU_CAMERAS]
    outlines, hints = load_corner_file(corners_file)
    calib = calibrate_floor(intr, {c: src / c / "checkerboard.avi" for c in UU_CAMERAS}, board,
                            outlines=outlines, origin_hints=hints, n_frames=n_frames, progress=progress)
    failed = calib.extrinsics.failed
    if failed:
        raise UUImportError("calibration failed for " + "; ".join(f"{c}: {why}" for c, why in failed.items()))
    out.mkdir(parents=True, exist_ok=True)
    for c in UU_CAMERAS:
        _place(src / c / "video.avi", out / f"{c}.avi", copy)
        _place(src / c / "background.avi", out / "background" / f"{c}.avi", copy)
    save_calibration(out / CALIBRATION_FILE, calib.extrinsics.cameras)
    write_session_toml(out, name=name, fps=next(iter(fps)),
                       cameras=[{"name": c, "video": f"{c}.avi", "background": f"background/{c}.avi"} for c in UU_CAMERAS])
    return ImportResult(out, next(iter(fps)), {c: infos[c][1] for c in UU_CAMERAS}, calib.extrinsics.cameras, calib)
