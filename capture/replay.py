"""Replay a recorded session: a camera source over session files, plus offline iterators.

``ReplaySource(session, "cam0")`` reads the camera's video (``cv2.VideoCapture``)
or image sequence (``cv2.imread``) and stamps each frame with its frame id and
timestamp from the session (``capture.session`` describes the numbering: CSV
row ``i`` = stored video frame ``i``, image file number = frame id, no CSV =
``k * 1e9 / fps``).  Gaps in a CSV's frame ids are dropped frames and come out
as skipped ids.

Pacing:

- ``"fast"``: every ``read()`` returns the next frame at once (offline, tests).
- ``"realtime"``: frame ``i`` is released at ``t0 + (timestamp_i - timestamp_0)``
  on the injected ``clock`` (``t0`` = clock at the first read), waiting with the
  injected ``sleep``; a reader that falls behind gets frames at once, none dropped.
- ``"step"``: the caller drives: ``step(n)`` grants ``n`` frames and ``read()``
  waits (up to ``step_timeout_s``, else ``SourceTimeout``) until one is granted.
  ``step`` may be called from another thread.

``loop=True`` restarts at the end; frame ids and timestamps keep increasing
(pass ``k`` adds ``k * (last_id - first_id + 1)`` to ids and
``k * (last_ts - first_ts + 1e9 / fps)`` to timestamps) so a synchroniser
downstream never sees an id twice.

``preload=True`` decodes the camera's footage into memory when opened and serves
it from there (a stand-in for a camera that delivers decoded frames: decoding is
then a cost of opening, not of reading).
"""

from __future__ import annotations

import heapq
import threading
import time
from pathlib import Path
from typing import Callable, Iterator, Sequence

import cv2
import numpy as np

from capture.errors import CaptureError
from capture.session import Session, image_frame_ids, image_path, read_timestamps
from capture.sources import EndOfStream, Frame, OpenError, SourceBase, SourceError, SourceTimeout

__all__ = ["ReplaySource", "read_frames", "iter_frame_sets", "parse_frame_range", "count_frames", "PACINGS",
           "FrameRangeError"]


class FrameRangeError(CaptureError, ValueError):
    """A ``--frames`` range that is malformed, or that holds no frame of the session (its length named)."""

PACINGS = ("fast", "realtime", "step")
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pbm"}


def parse_frame_range(text: str | None, *, option: str = "--frames") -> range | None:
    """The frame ids of a ``--frames`` option.

    Parameters
    ----------
    text : str or None
        ``"START:STOP"`` (STOP excluded; either may be empty: from 0 / to the end).
    option : str
        Option name for the error message.

    Returns
    -------
    range or None
        None for ``None`` or ``""`` (every frame); ``ValueError`` naming ``option`` on anything else.
    """
    if not text:
        return None
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start = int(parts[0]) if parts[0].strip() else 0
        stop = int(parts[1]) if parts[1].strip() else 2**62
    except ValueError:
        raise FrameRangeError(f"{option}: expected START:STOP (frame ids, STOP excluded), got {text!r}") from None
    if start < 0 or stop <= start:
        raise FrameRangeError(f"{option}: need 0 <= START < STOP, got {text!r}")
    return range(start, stop)


def count_frames(session: Session, camera: str, frames: range | None = None) -> int | None:
    """How many frames ``read_frames(session, camera, frames=frames)`` will give, for progress and ETA.

    Image sequences are counted exactly; videos by their containers' frame counts (summed over
    segment files, clipped to ``frames``).  None when unknown (a container without a count).
    """
    cam = session.camera(camera)
    if cam.images is not None:
        ids = image_frame_ids(cam.images)
        return int(sum(int(i) in frames for i in ids)) if frames is not None else int(ids.size)
    total = 0
    for path in cam.video_files:
        cap = cv2.VideoCapture(str(path))
        total += max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0)
        cap.release()
    if frames is not None:
        total = max(0, min(total, frames.stop) - max(frames.start, 0))
    return total or None


class _Reader:
    """One pass over a camera's stored frames: ``next() -> (frame_id, timestamp_ns, image) | None``."""

    def __init__(self, session: Session, camera: str, *, background: bool, frames: range | None):
        cam = session.camera(camera)
        self.frames = frames
        self.fps = session.fps
        self.ids: np.ndarray | None = None
        self.stamps: np.ndarray | None = None
        self.capture = None
        self.pattern: str | None = None
        self.single: Path | None = None
        self.index = 0
        if background:
            if cam.background is None:
                raise OpenError(f"camera {camera!r}: session {session.root} has no background for it")
            self.where = str(cam.background)
            if cam.background.suffix.lower() in _IMAGE_SUFFIXES:
                self.single = cam.background
            else:
                self.capture = _VideoChain([cam.background])
            return
        if cam.timestamps is not None:
            try:
                self.ids, self.stamps = read_timestamps(cam.timestamps)
            except ValueError as exc:
                raise OpenError(str(exc)) from None
        if cam.video is not None:
            self.where = str(cam.video)
            self.capture = _VideoChain(cam.video_files)
        else:
            self.where = cam.images
            self.pattern = cam.images
            if self.ids is None:
                self.ids = image_frame_ids(cam.images)
            if frames is not None:
                keep = np.array([int(i) in frames for i in self.ids], dtype=bool)
                self.ids, self.stamps = self.ids[keep], None if self.stamps is None else self.stamps[keep]

    def _stamp(self, fid: int, row: int) -> int:
        if self.stamps is not None:
            return int(self.stamps[row])
        return int(round(fid * 1e9 / self.fps))

    def next(self):
        if self.single is not None:
            if self.index > 0:
                return None
            self.index = 1
            return 0, 0, _imread(self.single)
        if self.pattern is not None:
            if self.index >= len(self.ids):
                return None
            row = self.index
            self.index += 1
            fid = int(self.ids[row])
            return fid, self._stamp(fid, row), _imread(image_path(self.pattern, fid))
        while True:  # video
            row = self.index
            if self.ids is not None and row >= len(self.ids):
                return None
            fid = int(self.ids[row]) if self.ids is not None else row
            if self.frames is not None and fid >= self.frames.stop:
                return None
            wanted = self.frames is None or fid in self.frames
            ok, image = self.capture.read() if wanted else (self.capture.grab(), None)
            if not ok:
                return None  # video ended (a cut recording may hold fewer frames than its CSV)
            self.index += 1
            if wanted:
                if image.ndim == 2:
                    image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
                return fid, self._stamp(fid, row), image

    def close(self):
        if self.capture is not None:
            self.capture.release()
            self.capture = None


class _Preloaded:
    """A ``_Reader`` pass decoded into memory: the same ``next()`` / ``close()``, plus ``rewind()``."""

    def __init__(self, reader: _Reader):
        self.where = reader.where
        self.items: list = []
        try:
            while (item := reader.next()) is not None:
                self.items.append(item)
        finally:
            reader.close()
        self.index = 0

    def next(self):
        if self.index >= len(self.items):
            return None
        self.index += 1
        return self.items[self.index - 1]

    def rewind(self) -> "_Preloaded":
        self.index = 0
        return self

    def close(self):
        self.items = []


class _VideoChain:
    """Video segment files read back to back (one file = one segment).

    A last segment that cannot be opened (a recording cut mid-segment) ends
    the stream; an earlier one is an error naming the file.
    """

    def __init__(self, paths: Sequence[Path]):
        self.paths = list(paths)
        if not self.paths:
            raise OpenError("no video segment files found")
        self.index = 0
        self.capture = _open_video(self.paths[0])

    def _advance(self) -> bool:
        self.capture.release()
        self.index += 1
        if self.index >= len(self.paths):
            return False
        try:
            self.capture = _open_video(self.paths[self.index])
        except OpenError:
            if self.index == len(self.paths) - 1:
                return False
            raise
        return True

    def read(self):
        while True:
            ok, image = self.capture.read()
            if ok or not self._advance():
                return ok, image

    def grab(self):
        while True:
            ok = self.capture.grab()
            if ok or not self._advance():
                return ok

    def release(self):
        self.capture.release()


def _open_video(path: Path):
    if not path.is_file():
        raise OpenError(f"{path}: video file not found")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise OpenError(f"{path}: OpenCV cannot open this video")
    return cap


def _imread(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if image is None:
        raise SourceError(f"{path}: image missing or unreadable")
    return image


class ReplaySource(SourceBase):
    """A camera source that replays one camera of a session (see module docstring).

    Parameters
    ----------
    session : Session
    camera_name : str
    pacing : {"fast", "realtime", "step"}
    clock : callable () -> int
        Nanosecond clock for ``realtime`` pacing (``time.monotonic_ns``).
    sleep : callable (seconds) -> None
    loop : bool
    frames : range or None
        Only frame ids in this range (positive step).
    background : bool
        Replay the camera's background media instead of its footage.
    step_timeout_s : float or None
        How long ``read()`` waits for ``step()`` in ``step`` pacing (None = forever).
    preload : bool
        Decode the footage into memory in ``open()`` and read from there.
    """

    def __init__(
        self,
        session: Session,
        camera_name: str,
        *,
        pacing: str = "fast",
        clock: Callable[[], int] = time.monotonic_ns,
        sleep: Callable[[float], None] = time.sleep,
        loop: bool = False,
        frames: range | None = None,
        background: bool = False,
        step_timeout_s: float | None = None,
        preload: bool = False,
    ):
        if pacing not in PACINGS:
            raise ValueError(f"pacing must be one of {PACINGS}, got {pacing!r}")
        if frames is not None and (not isinstance(frames, range) or frames.step <= 0):
            raise ValueError(f"frames must be a range with a positive step, got {frames!r}")
        session.camera(camera_name)  # SessionError naming the camera if absent
        self.session = session
        self.name = camera_name
        self.pacing = pacing
        self._clock = clock
        self._sleep = sleep
        self.loop = loop
        self.frames = frames
        self.background = background
        self.step_timeout_s = step_timeout_s
        self.preload = preload
        self._reader: _Reader | _Preloaded | None = None
        self._ended = False
        self._pass = 0
        self._first: tuple[int, int] | None = None  # (frame_id, timestamp_ns) of a pass's first frame
        self._last: tuple[int, int] | None = None
        self._start: tuple[int, int] | None = None  # (clock ns, timestamp ns) at the first delivered frame
        self._permits = 0
        self._cond = threading.Condition()

    def open(self) -> None:
        """Open the camera's media; raises ``OpenError`` naming the file."""
        self.close()
        self._reader = self._new_reader()
        self._ended = False

    def _new_reader(self) -> _Reader | _Preloaded:
        reader = _Reader(self.session, self.name, background=self.background, frames=self.frames)
        return _Preloaded(reader) if self.preload else reader

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def step(self, n: int = 1) -> None:
        """Grant ``n`` more frames to ``read()`` in ``step`` pacing."""
        with self._cond:
            self._permits += int(n)
            self._cond.notify_all()

    def _next_raw(self):
        item = self._reader.next()
        if item is not None or not self.loop or self._first is None:
            return item
        if isinstance(self._reader, _Preloaded):
            self._reader.rewind()
        else:
            self._reader.close()
            self._reader = self._new_reader()
        self._pass += 1
        return self._reader.next()

    def read(self) -> Frame:
        if self._reader is None:
            raise SourceError(f"replay camera {self.name!r}: read() on a source that is not open")
        if self._ended:
            raise EndOfStream(f"replay camera {self.name!r}: end of {self._reader.where}")
        if self.pacing == "step":
            with self._cond:
                if not self._cond.wait_for(lambda: self._permits > 0, timeout=self.step_timeout_s):
                    raise SourceTimeout(f"replay camera {self.name!r}: no step() within {self.step_timeout_s} s")
                self._permits -= 1
        item = self._next_raw()
        if item is None:
            self._ended = True
            raise EndOfStream(f"replay camera {self.name!r}: end of {self._reader.where}")
        fid, ts, image = item
        if self._pass == 0:
            if self._first is None:
                self._first = (fid, ts)
            self._last = (fid, ts)
        else:
            period_ids = self._last[0] - self._first[0] + 1
            period_ns = self._last[1] - self._first[1] + int(round(1e9 / self.session.fps))
            fid += self._pass * period_ids
            ts += self._pass * period_ns
        if self.pacing == "realtime":
            now = self._clock()
            if self._start is None:
                self._start = (now, ts)
            due = self._start[0] + (ts - self._start[1])
            if due > now:
                self._sleep((due - now) / 1e9)
        return Frame(self.name, fid, ts, image)


def read_frames(
    session: Session, camera_name: str, *, frames: range | None = None, background: bool = False
) -> Iterator[Frame]:
    """All frames of one camera in order (fast pacing, no loop)."""
    with ReplaySource(session, camera_name, frames=frames, background=background) as src:
        while True:
            try:
                yield src.read()
            except EndOfStream:
                return


def iter_frame_sets(
    session: Session, *, cameras: Sequence[str] | None = None, frames: range | None = None
) -> Iterator[tuple[int, dict[str, Frame]]]:
    """Frame sets of a session in frame-id order, offline and lossless.

    Yields ``(frame_id, {camera: Frame})`` for every frame id that at least
    one camera stored; a camera that dropped that frame is absent from the dict.
    """
    names = list(session.camera_names if cameras is None else cameras)
    iters = {n: read_frames(session, n, frames=frames) for n in names}
    heap: list[tuple[int, int, Frame]] = []
    for order, n in enumerate(names):
        first = next(iters[n], None)
        if first is not None:
            heapq.heappush(heap, (first.frame_id, order, first))
    try:
        while heap:
            fid = heap[0][0]
            group: dict[str, Frame] = {}
            while heap and heap[0][0] == fid:
                _, order, frame = heapq.heappop(heap)
                group[frame.camera] = frame
                following = next(iters[names[order]], None)
                if following is not None:
                    heapq.heappush(heap, (following.frame_id, order, following))
            yield fid, {n: group[n] for n in names if n in group}
    finally:
        for it in iters.values():
            it.close()
