"""Session directories: what replay reads, what ``record`` writes, what ``track`` takes.

Layout (the DESIGN.md contract)::

    SESSION/
      session.toml        see below
      calibration.toml    anipose layout (capture.calibration), metres, world Z up
      cam0.avi …          one video or image sequence per camera; frame k = trigger pulse k
      cam0.csv …          optional: ``frame_id,timestamp_ns`` per stored frame (gaps = dropped frames)

``session.toml``::

    [session]
    name = "take1"
    fps = 50.0

    [subject]                     # optional
    height_m = 1.75
    file = "subject.toml"         # optional: a fitted subject (contourcap calibrate subject), wins
    [subject.segment_lengths]     # optional, metres, keyed by segment name
    upper_arm = 0.29

    [[camera]]
    name = "cam0"
    video = "cam0.avi"            # or segments: "cam0/%06d.avi" (number = first stored frame's index)
                                  # or: images = "cam0/%06d.png" (printf pattern, number = frame id)
    background = "background/cam0.avi"   # optional
    timestamps = "cam0.csv"              # optional
    ignore = [[x, y, w, h]]              # optional: pixel boxes that are never body (segmentation.clutter)

    [[prop]]                      # optional, repeatable: a world box that is never body (a chair)
    box = [x0, y0, z0, x1, y1, z1]   # metres, calibration frame (tracker.fitting.props)
    hollow = true                 # optional: an outline (a chair's bounding box) seen through where
                                  # no solid [[prop]] (its seat, its legs) is in the way

Frame numbering: row ``i`` of a camera's CSV describes the ``i``-th frame
stored in its video; for an image sequence the file number *is* the frame id.
Without a CSV, video frame ``k`` has frame id ``k`` and
``timestamp_ns = k * 1e9 / fps``.  A ``video`` holding a printf pattern names
segment files read back to back as one video (the recorder writes 1-second
segments so a crash loses at most the last one); read media through
``capture.replay`` rather than opening ``video`` directly.  Paths are relative
to the session root.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from capture.atomic import write_text_atomic
from capture.calibration import CalibrationError, load_calibration
from capture.camera import Camera
from capture.errors import CaptureError
from capture.tomlio import dumps, load_file

__all__ = [
    "SessionError",
    "SessionCamera",
    "Session",
    "load_session",
    "check_box",
    "write_session_toml",
    "read_timestamps",
    "image_frame_ids",
    "image_path",
    "SESSION_FILE",
    "CALIBRATION_FILE",
]

SESSION_FILE = "session.toml"
CALIBRATION_FILE = "calibration.toml"
_CAMERA_KEYS = {"name", "video", "images", "background", "timestamps", "ignore"}
_PATTERN = re.compile(r"%(0?)(\d*)d")


class SessionError(CaptureError, ValueError):
    """A session directory is malformed; the message names the file, key or camera."""


@dataclass(frozen=True)
class SessionCamera:
    """One camera's media in a session; paths are absolute.

    ``images`` is an absolute printf pattern (``/…/cam0/%06d.png``) whose
    number is the frame id.  Exactly one of ``video`` / ``images`` is set.
    """

    name: str
    video: Path | None
    images: str | None
    background: Path | None
    timestamps: Path | None

    @property
    def video_files(self) -> tuple[Path, ...]:
        """The video file, or the segment files of a ``%0Nd`` video pattern in order; () for images."""
        if self.video is None:
            return ()
        if "%" not in self.video.name:
            return (self.video,)
        return tuple(image_path(str(self.video), n) for n in image_frame_ids(str(self.video)))


@dataclass(frozen=True)
class Session:
    """A loaded, validated session directory.

    ``calibration`` holds one ``Camera`` per entry of ``cameras``, same order,
    matched by name (empty only when loaded with ``require_calibration=False``
    and no calibration file exists).
    """

    root: Path
    name: str
    fps: float
    height_m: float | None
    segment_lengths: dict[str, float] | None
    cameras: tuple[SessionCamera, ...]
    calibration: tuple[Camera, ...]
    subject_file: Path | None = None
    #: ``[[prop]]`` boxes, each (x0, y0, z0, x1, y1, z1) metres with x0 < x1, y0 < y1, z0 < z1
    props: tuple[tuple[float, ...], ...] = ()
    #: per ``[[prop]]``, whether it is ``hollow`` (empty: none is)
    hollow_props: tuple[bool, ...] = ()

    @property
    def camera_names(self) -> tuple[str, ...]:
        """Camera names in session order."""
        return tuple(c.name for c in self.cameras)

    def camera(self, name: str) -> SessionCamera:
        """The session's camera ``name`` (its media); ``SessionError`` naming the file if absent."""
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise SessionError(f"{self.root / SESSION_FILE}: no camera named {name!r} (have {list(self.camera_names)})")

    def camera_model(self, name: str) -> Camera:
        """The calibrated ``Camera`` of ``name``; ``SessionError`` if the calibration lacks it."""
        for cam in self.calibration:
            if cam.name == name:
                return cam
        if not self.calibration:
            raise SessionError(f"{self.root}: session has no {CALIBRATION_FILE}")
        raise SessionError(f"{self.root / CALIBRATION_FILE}: no camera named {name!r}")


def image_path(pattern: str, frame_id: int) -> Path:
    """The file of ``frame_id`` in a printf image pattern (``cam0/%06d.png``)."""
    return Path(pattern % int(frame_id))


def image_frame_ids(pattern: str) -> np.ndarray:
    """Frame ids of the files present for a printf image pattern, ascending.

    Returns
    -------
    ndarray, shape (n,), int64
    """
    p = Path(pattern)
    match = _PATTERN.search(p.name)
    if match is None or len(_PATTERN.findall(p.name)) != 1 or "%" in str(p.parent):
        raise SessionError(f"image pattern {pattern!r} must hold exactly one %d / %0Nd in its file name")
    head, tail = p.name[: match.start()], p.name[match.end() :]
    regex = re.compile(re.escape(head) + r"(\d+)" + re.escape(tail) + r"\Z")
    if not p.parent.is_dir():
        return np.zeros(0, dtype=np.int64)
    ids = [int(m.group(1)) for f in p.parent.iterdir() if (m := regex.match(f.name))]
    return np.array(sorted(set(ids)), dtype=np.int64)


def read_timestamps(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a ``frame_id,timestamp_ns`` CSV (header line required).

    Returns
    -------
    frame_ids : ndarray, shape (n,), int64, strictly increasing
    timestamps_ns : ndarray, shape (n,), int64, non-decreasing
    """
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise SessionError(f"{path}: timestamps file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SessionError(f"{path}: cannot read timestamps: {exc}") from None
    if not lines or [c.strip() for c in lines[0].split(",")] != ["frame_id", "timestamp_ns"]:
        raise SessionError(f"{path}: first line must be the header 'frame_id,timestamp_ns'")
    ids, stamps = [], []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = line.split(",")
        try:
            if len(parts) != 2:
                raise ValueError("expected 2 columns")
            ids.append(int(parts[0]))
            stamps.append(int(parts[1]))
        except ValueError as exc:
            raise SessionError(f"{path}:{lineno}: bad row {line!r}: {exc}") from None
    frame_ids = np.array(ids, dtype=np.int64)
    timestamps = np.array(stamps, dtype=np.int64)
    if frame_ids.size and (frame_ids[0] < 0 or np.any(np.diff(frame_ids) <= 0)):
        raise SessionError(f"{path}: frame_id must be non-negative and strictly increasing")
    if np.any(np.diff(timestamps) < 0):
        raise SessionError(f"{path}: timestamp_ns must be non-decreasing")
    return frame_ids, timestamps


def _resolve(root: Path, value, where: str) -> Path:
    """``root / value`` for a path written in the session file, which must stay inside the session
    folder: relative, without a ``..`` that leaves it (checked on the text: a symlink placed inside the
    folder, as ``contourcap import`` makes, is the operator's choice and is followed)."""
    if not isinstance(value, str) or not value or "\x00" in value:
        raise SessionError(f"{where}: must be a non-empty string path")
    p = Path(value)
    norm = os.path.normpath(value)
    if p.is_absolute() or p.drive or norm == ".." or norm.startswith(".." + os.sep) or norm.startswith("../"):
        raise SessionError(f"{where}: {value!r} leaves the session folder (paths must be relative to it, "
                           "without '..'); place the file, or a symlink to it, inside the folder")
    return root / p


def _optional_path(root: Path, table: dict, key: str, where: str) -> Path | None:
    if key not in table:
        return None
    path = _resolve(root, table[key], f"{where} key {key!r}")
    if not path.exists():
        raise SessionError(f"{where}: {key} file {path} not found")
    return path


def _frame_ids(pattern: str, where: str) -> np.ndarray:
    """``image_frame_ids`` with the session file and camera named in its error."""
    try:
        return image_frame_ids(pattern)
    except SessionError as exc:
        raise SessionError(f"{where}: {exc}") from None


def _parse_camera(root: Path, table, index: int, where_file: Path) -> SessionCamera:
    where = f"{where_file} [[camera]] #{index}"
    if not isinstance(table, dict):
        raise SessionError(f"{where}: must be a table")
    unknown = set(table) - _CAMERA_KEYS
    if unknown:
        raise SessionError(f"{where}: unknown key(s) {sorted(unknown)}")
    name = table.get("name")
    if not isinstance(name, str) or not name:
        raise SessionError(f"{where}: missing key 'name' (a non-empty string)")
    where = f"{where_file} camera {name!r}"
    if ("video" in table) == ("images" in table):
        raise SessionError(f"{where}: exactly one of 'video' or 'images' is required")
    video = images = None
    if "video" in table:
        video = _resolve(root, table["video"], f"{where} key 'video'")
        if "%" in video.name:
            if _frame_ids(str(video), where).size == 0:
                raise SessionError(f"{where}: no video segment files match pattern {str(video)!r}")
        elif not video.is_file():
            raise SessionError(f"{where}: video file {video} not found")
    else:
        images = str(_resolve(root, table["images"], f"{where} key 'images'"))
        if _frame_ids(images, where).size == 0:
            raise SessionError(f"{where}: no image files match pattern {images!r}")
    background = _optional_path(root, table, "background", where)
    timestamps = _optional_path(root, table, "timestamps", where)
    return SessionCamera(name, video, images, background, timestamps)


def _parse_subject(subject, where: str) -> tuple[float | None, dict[str, float] | None]:
    if not isinstance(subject, dict):
        raise SessionError(f"{where} [subject]: must be a table")
    height = subject.get("height_m")
    if height is not None:
        if isinstance(height, bool) or not isinstance(height, (int, float)) or not 0.3 < height < 3.0:
            raise SessionError(f"{where} [subject] key 'height_m': must be a number of metres in (0.3, 3.0), got {height!r}")
        height = float(height)
    lengths = subject.get("segment_lengths")
    if lengths is not None:
        if not isinstance(lengths, dict):
            raise SessionError(f"{where} [subject.segment_lengths]: must be a table of name = metres")
        out = {}
        for k, v in lengths.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise SessionError(f"{where} [subject.segment_lengths] key {k!r}: must be a positive number of metres")
            out[str(k)] = float(v)
        lengths = out
    return height, lengths


MAX_PROPS = 16
"""At most this many ``[[prop]]`` tables."""
MAX_BOX_COORD_M = 100.0
"""A prop box's coordinates lie within this many metres of the origin."""
MAX_BOX_SIDE_M = 10.0
"""A prop box's sides are at most this long (metres)."""


def check_box(values, where: str, error: type[Exception] = ValueError) -> tuple[float, ...]:
    """A world box ``[x0, y0, z0, x1, y1, z1]`` (metres, corners in any order per axis) validated:
    six finite numbers within 100 m, each side 0-10 m; returned ordered as (x0, y0, z0, x1, y1, z1)
    with x0 < x1, y0 < y1, z0 < z1.  Otherwise ``error`` whose message starts with ``where``."""
    if (isinstance(values, (str, bytes)) or not hasattr(values, "__len__") or len(values) != 6
            or any(isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) for v in values)):
        raise error(f"{where}: expected [x0, y0, z0, x1, y1, z1] in metres, got {values!r}")
    box = [float(v) for v in values]
    if not all(math.isfinite(v) and abs(v) <= MAX_BOX_COORD_M for v in box):
        raise error(f"{where}: coordinates must be finite and within {MAX_BOX_COORD_M:g} m, got {values!r}")
    lo = [min(box[k], box[k + 3]) for k in range(3)]
    hi = [max(box[k], box[k + 3]) for k in range(3)]
    if not all(0.0 < h - l <= MAX_BOX_SIDE_M for l, h in zip(lo, hi)):
        raise error(f"{where}: every side must be > 0 and <= {MAX_BOX_SIDE_M:g} m, got {values!r}")
    return tuple(lo + hi)


def _parse_props(tables, where: str) -> tuple[tuple[tuple[float, ...], ...], tuple[bool, ...]]:
    """The ``[[prop]]`` tables' boxes, validated by :func:`check_box`, and their ``hollow`` flags
    (default false)."""
    if tables is None:
        return (), ()
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        raise SessionError(f"{where}: 'prop' must be [[prop]] tables")
    if len(tables) > MAX_PROPS:
        raise SessionError(f"{where}: at most {MAX_PROPS} [[prop]] tables, got {len(tables)}")
    boxes, hollow = [], []
    for i, t in enumerate(tables):
        boxes.append(check_box(t.get("box"), f"{where} [[prop]] #{i + 1} key 'box'", SessionError))
        flag = t.get("hollow", False)
        if not isinstance(flag, bool):
            raise SessionError(f"{where} [[prop]] #{i + 1} key 'hollow': expected true or false, got {flag!r}")
        hollow.append(flag)
    return tuple(boxes), tuple(hollow)


def load_session(path, *, require_calibration: bool = True) -> Session:
    """Load and validate a session directory (or its ``session.toml``).

    Checks that every media file exists, camera names are unique and the
    calibration holds every camera.  ``require_calibration=False`` accepts a
    session without ``calibration.toml`` (e.g. checkerboard footage to be
    calibrated); a calibration that exists is still loaded and checked.

    Raises
    ------
    SessionError
        naming the file, key or camera at fault.
    """
    path = Path(path)
    root = path.parent if path.is_file() else path
    toml_path = path if path.is_file() else root / SESSION_FILE
    if not toml_path.is_file():
        raise SessionError(f"{toml_path}: session file not found")
    data = load_file(toml_path, error=SessionError, what="session file")
    sess = data.get("session")
    if not isinstance(sess, dict):
        raise SessionError(f"{toml_path}: missing table [session]")
    name = sess.get("name")
    if not isinstance(name, str) or not name:
        raise SessionError(f"{toml_path} [session]: missing key 'name' (a non-empty string)")
    fps = sess.get("fps")
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
        raise SessionError(f"{toml_path} [session] key 'fps': must be a positive number, got {fps!r}")
    height, lengths = _parse_subject(data.get("subject", {}), str(toml_path))
    tables = data.get("camera")
    if not isinstance(tables, list) or not tables:
        raise SessionError(f"{toml_path}: needs at least one [[camera]] table")
    cameras = tuple(_parse_camera(root, t, i, toml_path) for i, t in enumerate(tables))
    names = [c.name for c in cameras]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SessionError(f"{toml_path}: camera names must be unique, repeated: {dup}")
    calib_path = root / CALIBRATION_FILE
    calibration: tuple[Camera, ...] = ()
    if calib_path.is_file() or require_calibration:
        try:
            by_name = {c.name: c for c in load_calibration(calib_path)}
        except CalibrationError as exc:
            raise SessionError(f"session {root}: {exc}") from None
        missing = [n for n in names if n not in by_name]
        if missing:
            raise SessionError(f"{calib_path}: no calibration for camera(s) {missing} (has {sorted(by_name)})")
        calibration = tuple(by_name[n] for n in names)
    subject_file = _optional_path(root, data.get("subject", {}), "file", f"{toml_path} [subject]")
    props, hollow = _parse_props(data.get("prop"), str(toml_path))
    return Session(root, name, float(fps), height, lengths, cameras, calibration, subject_file, props, hollow)


def write_session_toml(
    root,
    *,
    name: str,
    fps: float,
    cameras: Sequence[Mapping],
    height_m: float | None = None,
    segment_lengths: Mapping[str, float] | None = None,
) -> Path:
    """Write ``root/session.toml``; ``cameras`` are dicts with the ``[[camera]]`` keys.

    Paths in the camera dicts are written as given (relative to ``root`` is
    the norm).  Does not check that media exist: the recorder writes this
    file *before* the first frame so a crash still leaves a readable session.
    """
    root = Path(root)
    if not name:
        raise SessionError("write_session_toml: 'name' must be non-empty")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and fps > 0):
        raise SessionError(f"write_session_toml: 'fps' must be positive, got {fps!r}")
    cams = []
    for i, cam in enumerate(cameras):
        unknown = set(cam) - _CAMERA_KEYS
        if unknown or "name" not in cam or (("video" in cam) == ("images" in cam)):
            raise SessionError(
                f"write_session_toml: camera #{i} needs 'name' and exactly one of 'video'/'images'"
                f" (unknown keys: {sorted(unknown)})"
            )
        cams.append({k: str(v) for k, v in cam.items() if v is not None})
    names = [c["name"] for c in cams]
    if not cams or len(set(names)) != len(names):
        raise SessionError(f"write_session_toml: camera names must be unique and non-empty, got {names}")
    data: dict = {"session": {"name": name, "fps": float(fps)}}
    if height_m is not None or segment_lengths:
        subject: dict = {}
        if height_m is not None:
            subject["height_m"] = float(height_m)
        if segment_lengths:
            subject["segment_lengths"] = {str(k): float(v) for k, v in segment_lengths.items()}
        data["subject"] = subject
    data["camera"] = cams
    root.mkdir(parents=True, exist_ok=True)
    out = root / SESSION_FILE
    write_text_atomic(out, dumps(data))
    return out
