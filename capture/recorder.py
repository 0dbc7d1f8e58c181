"""Record live sources into a session directory that survives a crash.

Output (the ``capture.session`` contract)::

    OUT/session.toml       written FIRST, before any frame
    OUT/calibration.toml   copied in (when given)
    OUT/cam0.csv           frame_id,timestamp_ns; one row per stored frame, flushed per row
    OUT/cam0/000012.png    codec "png": one file per frame, named by frame id (lossless)
    OUT/cam0/000000.avi    codec "ffv1" (lossless) / "mjpg" (fast, lossy): 1-second
                           segment files named by their first stored frame's index

Crash safety: PNGs are written to a temporary name and renamed, then their CSV
row is written and flushed; a video segment is closed (and its frame count
verified) every ``segment_s`` seconds, so a crash loses at most the segment
being written.  ``capture.replay`` reads a cut session (stops where the media
stop).  Write failures are never silent: a failed write raises
``RecorderError`` (``DiskFullError`` for ENOSPC / EDQUOT, or when free space
drops below ``min_free_bytes``, checked once per second of footage) naming
the file.  ``cv2.VideoWriter`` cannot report errors, hence the frame-count
check of every closed segment.

``load_capture_config`` reads the capture part of the service's ``studio.toml``
(``capture.studio``) and loads its replay session.
"""

from __future__ import annotations

import errno
import os
import shutil
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from capture.atomic import write_bytes_atomic
from capture.calibration import CalibrationError, load_calibration
from capture.errors import CaptureError
from capture.session import CALIBRATION_FILE, Session, SessionError, load_session, write_session_toml
from capture.backends import SourceSpec
from capture.sources import EndOfStream, Frame, SourceError
from capture.studio import parse_studio_capture, read_studio_toml

__all__ = [
    "CODECS",
    "RecorderError",
    "DiskFullError",
    "CameraRecording",
    "RecordingSummary",
    "Recorder",
    "record",
    "CaptureConfig",
    "load_capture_config",
]

CODECS = {"png": None, "ffv1": ("FFV1", ".avi"), "mjpg": ("MJPG", ".avi")}
_FULL = {errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)}


class RecorderError(CaptureError):
    """Recording failed; the message names the file or camera."""


class DiskFullError(RecorderError):
    """The disk is (nearly) full."""


@dataclass(frozen=True)
class CameraRecording:
    """What one camera stored.

    Attributes
    ----------
    name : str
    frames : int
        Frames stored.
    first_frame_id, last_frame_id : int or None
        Ids of the first and last stored frame (None: nothing stored).
    dropped : int
        Gaps in frame ids between the first and last stored frame.
    rejected : int
        Frames whose id was not above the previous one (not stored).
    error : str or None
        Why this camera's source stopped early.
    """

    name: str
    frames: int
    first_frame_id: int | None
    last_frame_id: int | None
    dropped: int
    rejected: int
    error: str | None = None


@dataclass(frozen=True)
class RecordingSummary:
    """The session directory written and each camera's :class:`CameraRecording`."""

    root: Path
    cameras: tuple[CameraRecording, ...]


def _oserror(exc: OSError, what: str) -> RecorderError:
    cls = DiskFullError if exc.errno in _FULL else RecorderError
    return cls(f"{what}: {exc.strerror or exc}")


class _CameraWriter:
    def __init__(self, root: Path, name: str, codec: str, fps: float, segment_frames: int, check_space: Callable[[str], None]):
        self.root, self.name, self.codec, self.fps = root, name, codec, fps
        self.segment_frames = segment_frames
        self.check_space = check_space
        self.dir = root / name
        self.dir.mkdir()
        self.csv_path = root / f"{name}.csv"
        try:
            self.csv = open(self.csv_path, "w", encoding="ascii", newline="\n")
            self.csv.write("frame_id,timestamp_ns\n")
            self.csv.flush()
        except OSError as exc:
            raise _oserror(exc, str(self.csv_path)) from None
        self.lock = threading.Lock()
        self.count = 0
        self.first: int | None = None
        self.last: int | None = None
        self.rejected = 0
        self.size: tuple[int, int] | None = None
        self.writer = None
        self.segment_path: Path | None = None
        self.segment_count = 0
        self.failed: str | None = None

    def entry(self) -> dict:
        pattern = "%06d.png" if self.codec == "png" else "%06d" + CODECS[self.codec][1]
        key = "images" if self.codec == "png" else "video"
        return {"name": self.name, key: f"{self.name}/{pattern}", "timestamps": f"{self.name}.csv"}

    def write(self, frame: Frame) -> None:
        with self.lock:
            if self.failed:
                raise RecorderError(f"camera {self.name!r}: recording already failed: {self.failed}")
            fid = int(frame.frame_id)
            if self.last is not None and fid <= self.last:
                self.rejected += 1
                return
            image = np.ascontiguousarray(frame.image)
            if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
                raise RecorderError(f"camera {self.name!r}: frame {fid} is not a (h, w, 3) uint8 image: {image.dtype} {image.shape}")
            size = (image.shape[1], image.shape[0])
            if self.size is None:
                self.size = size
            elif size != self.size:
                raise RecorderError(f"camera {self.name!r}: frame {fid} is {size[0]}x{size[1]}, earlier frames {self.size[0]}x{self.size[1]}")
            try:
                if self.count % self.segment_frames == 0:
                    self.check_space(self.name)
                if self.codec == "png":
                    self._write_png(fid, image)
                else:
                    self._write_video(image)
                self.csv.write(f"{fid},{int(frame.timestamp_ns)}\n")
                self.csv.flush()
            except RecorderError as exc:
                self.failed = str(exc)
                raise
            except OSError as exc:
                err = _oserror(exc, f"camera {self.name!r} ({self.csv_path if self.codec != 'png' else self.dir})")
                self.failed = str(err)
                raise err from None
            self.count += 1
            self.first = fid if self.first is None else self.first
            self.last = fid

    def _write_png(self, fid: int, image: np.ndarray) -> None:
        path = self.dir / f"{fid:06d}.png"
        ok, data = cv2.imencode(".png", image)
        if not ok:
            raise RecorderError(f"{path}: PNG encoding failed")
        tmp = path.with_name(path.name + ".tmp")
        try:
            with open(tmp, "wb") as fh:
                fh.write(data.tobytes())
            os.replace(tmp, path)
        except OSError as exc:
            raise _oserror(exc, str(path)) from None

    def _write_video(self, image: np.ndarray) -> None:
        if self.writer is None or self.segment_count >= self.segment_frames:
            self._close_segment()
            fourcc, ext = CODECS[self.codec]
            self.segment_path = self.dir / f"{self.count:06d}{ext}"
            self.writer = cv2.VideoWriter(str(self.segment_path), cv2.VideoWriter_fourcc(*fourcc), self.fps, self.size)
            if not self.writer.isOpened():
                self.writer = None
                raise RecorderError(f"{self.segment_path}: cv2.VideoWriter cannot write {fourcc}")
            self.segment_count = 0
        self.writer.write(image)
        self.segment_count += 1

    def _close_segment(self) -> None:
        if self.writer is None:
            return
        self.writer.release()
        self.writer = None
        cap = cv2.VideoCapture(str(self.segment_path))
        stored = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        if stored != self.segment_count:
            raise RecorderError(
                f"{self.segment_path}: holds {stored} of {self.segment_count} frames written (disk full or write error?)"
            )

    def close(self, error: str | None = None) -> CameraRecording:
        with self.lock:
            problem = None
            try:
                self._close_segment()
            except RecorderError as exc:
                problem = str(exc)
            try:
                self.csv.close()
            except OSError as exc:
                problem = problem or str(_oserror(exc, str(self.csv_path)))
            dropped = 0 if self.first is None else (self.last - self.first + 1 - self.count)
            if problem and not self.failed:
                self.failed = problem
            return CameraRecording(self.name, self.count, self.first, self.last, dropped, self.rejected, error or self.failed)


class Recorder:
    """Write frames of named cameras into a new session directory (see module docstring).

    Parameters
    ----------
    root : path
        Output directory; must not exist or be empty (a session is never overwritten).
    name, fps : session name and nominal frame rate.
    cameras : sequence of str
    codec : {"png", "ffv1", "mjpg"}
    calibration : path, optional
        Calibration TOML to copy in; must hold every camera.
    segment_s : float
        Video segment length (and free-space check interval), seconds.
    min_free_bytes : int
        ``DiskFullError`` when less is free before a segment / second of PNGs.
    disk_usage : callable
        ``shutil.disk_usage`` (injected for tests).
    """

    def __init__(
        self,
        root,
        *,
        name: str,
        fps: float,
        cameras: Sequence[str],
        codec: str = "png",
        calibration=None,
        segment_s: float = 1.0,
        height_m: float | None = None,
        min_free_bytes: int = 64 << 20,
        disk_usage: Callable = shutil.disk_usage,
    ):
        if codec not in CODECS:
            raise ValueError(f"codec must be one of {sorted(CODECS)}, got {codec!r}")
        if not (fps > 0 and segment_s > 0):
            raise ValueError(f"fps and segment_s must be positive, got {fps}, {segment_s}")
        self.root = Path(root)
        if self.root.exists() and (not self.root.is_dir() or any(self.root.iterdir())):
            raise RecorderError(f"{self.root}: output exists and is not an empty directory (never overwritten)")
        names = list(cameras)
        if not names or len(set(names)) != len(names):
            raise ValueError(f"cameras must be non-empty and unique, got {names}")
        calib_text = None
        if calibration is not None:
            try:
                have = {c.name for c in load_calibration(calibration)}
            except CalibrationError as exc:
                raise RecorderError(str(exc)) from None
            missing = [n for n in names if n not in have]
            if missing:
                raise RecorderError(f"{calibration}: no calibration for camera(s) {missing}")
            calib_text = Path(calibration).read_bytes()
        self.min_free_bytes = int(min_free_bytes)
        self._disk_usage = disk_usage
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            seg = max(1, int(round(segment_s * fps)))
            self._writers = {n: _CameraWriter(self.root, n, codec, fps, seg, self._check_space) for n in names}
            self._session = {"name": name, "fps": fps, "height_m": height_m}
            write_session_toml(self.root, cameras=[w.entry() for w in self._writers.values()], **self._session)
            if calib_text is not None:
                write_bytes_atomic(self.root / CALIBRATION_FILE, calib_text)
        except OSError as exc:
            raise _oserror(exc, str(self.root)) from None
        self._closed: RecordingSummary | None = None

    def add_backgrounds(self, backgrounds: dict[str, str]) -> None:
        """List background plates (camera -> path relative to the session, from
        ``capture.background_take.record_background``) in ``session.toml`` (rewritten atomically)."""
        unknown = sorted(set(backgrounds) - set(self._writers))
        if unknown:
            raise RecorderError(f"{self.root}: background for camera(s) {unknown} not being recorded")
        entries = [{**w.entry(), **({"background": backgrounds[n]} if n in backgrounds else {})}
                   for n, w in self._writers.items()]
        try:
            write_session_toml(self.root, cameras=entries, **self._session)
        except OSError as exc:
            raise _oserror(exc, str(self.root)) from None

    def _check_space(self, camera: str) -> None:
        free = self._disk_usage(self.root).free
        if free < self.min_free_bytes:
            raise DiskFullError(
                f"{self.root}: only {free / 2**20:.1f} MiB free (< {self.min_free_bytes / 2**20:.0f} MiB); stopped camera {camera!r}"
            )

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def write(self, frame: Frame) -> None:
        """Store one frame (thread-safe across cameras); raises ``RecorderError`` on failure."""
        writer = self._writers.get(frame.camera)
        if writer is None:
            raise RecorderError(f"{self.root}: camera {frame.camera!r} is not being recorded (have {list(self._writers)})")
        writer.write(frame)

    def close(self, errors: dict[str, str] | None = None) -> RecordingSummary:
        """Finish every camera; returns what was stored (idempotent)."""
        if self._closed is None:
            errors = errors or {}
            cams = tuple(w.close(errors.get(n)) for n, w in self._writers.items())
            self._closed = RecordingSummary(self.root, cams)
        return self._closed


def record(sources: Sequence, recorder: Recorder, *, max_frames: int | None = None, stop: threading.Event | None = None) -> RecordingSummary:
    """Read every source on its own thread into ``recorder`` until end, ``max_frames`` each, or ``stop``.

    A source that fails (``StreamLostError`` …) stops alone and is named in
    its ``CameraRecording.error``; a recorder failure stops all and is raised.

    Parameters
    ----------
    sources : sequence of Source
        Not yet opened; each is entered on its thread.
    recorder : Recorder
        Closed at the end.
    max_frames : int, optional
        Frames per camera.
    stop : threading.Event, optional
        Set to end the recording (also set by a recorder failure).

    Returns
    -------
    RecordingSummary
    """
    stop = threading.Event() if stop is None else stop
    errors: dict[str, str] = {}
    fatal: list[RecorderError] = []

    def run(src) -> None:
        n = 0
        try:
            with src:
                while not stop.is_set() and (max_frames is None or n < max_frames):
                    frame = src.read()
                    recorder.write(frame)
                    n += 1
        except EndOfStream:
            pass
        except SourceError as exc:
            errors[src.name] = f"{type(exc).__name__}: {exc}"
        except RecorderError as exc:
            fatal.append(exc)
            errors[src.name] = f"{type(exc).__name__}: {exc}"
            stop.set()
        except Exception as exc:  # a backend bug must not end this camera silently (a thread's error is lost)
            errors[src.name] = f"unexpected {type(exc).__name__}: {exc}"

    threads = [threading.Thread(target=run, args=(s,), name=f"record-{s.name}", daemon=True) for s in sources]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    summary = recorder.close(errors)
    if fatal:
        raise fatal[0]
    return summary


@dataclass(frozen=True)
class CaptureConfig:
    """The capture part of a studio config, its replay session loaded.

    Attributes
    ----------
    name : str
        Studio name (the default session name).
    fps : float
        Frames per second (see ``capture.studio.StudioCapture.fps``).
    trigger : {"none", "usb"}
    session : Session or None
        The replay session, loaded when a camera uses the replay backend.
    calibration : Path or None
        ``[studio] calibration``, else the session's ``calibration.toml`` when it has one.
    cameras : tuple of SourceSpec
    """

    name: str
    fps: float
    trigger: str  # "none" | "usb"
    session: Session | None
    calibration: Path | None
    cameras: tuple[SourceSpec, ...]


def load_capture_config(path) -> CaptureConfig:
    """Read the capture part of ``studio.toml`` (``capture.studio``); ``RecorderError`` names file and key."""
    path = Path(path)
    try:
        cap = parse_studio_capture(read_studio_toml(path), where=str(path), base=path.resolve().parent)
    except ValueError as exc:
        raise RecorderError(str(exc)) from None
    session = None
    if any(c.backend == "replay" for c in cap.cameras):
        try:
            session = load_session(cap.session, require_calibration=False)
        except SessionError as exc:
            raise RecorderError(f"{path}: studio.session: {exc}") from None
    calibration = cap.calibration
    if calibration is None and session is not None and (session.root / CALIBRATION_FILE).is_file():
        calibration = session.root / CALIBRATION_FILE
    return CaptureConfig(cap.name, cap.fps, cap.trigger, session, calibration, cap.cameras)
