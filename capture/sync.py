"""Frame-set synchroniser: frames from N cameras -> frame sets by frame id, in order.

Pure and single-threaded: ``push(frame)`` stores, ``poll(now_ns)`` returns the
sets that are ready, ``stats`` counts what went wrong.  Time comes only from
the caller (``now_ns`` on the same clock for every call).

Rules, for the oldest pending set (sets leave strictly in frame-id order):

- **complete**: every expected camera delivered -> emitted.
- **skipped**: every missing camera has already delivered a *later* id
  (cameras deliver in order, so it dropped this one) -> emitted at once,
  naming the missing cameras.
- **timeout**: ``timeout_ns`` passed since the set's first frame arrived ->
  emitted incomplete, naming the missing cameras.
- A camera silent for ``stop_after_ns`` is *stopped*: sets no longer wait for
  it (listed in ``stats.stopped``) until it delivers again.

Bad input is counted, never raised: a *duplicate* (camera, id) is dropped; a
*late* frame (its id was already emitted) is dropped; an *out-of-order* frame
(id below that camera's newest) is counted and still used if its set is
pending; a frame of an unknown camera is dropped.  Memory is bounded: at most
``max_pending`` sets of at most ``n_cams`` frames; beyond that the oldest
pending set is discarded (sets counted in ``overflow``, their frames in
``discarded_frames``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

from capture.sources import Frame

__all__ = ["FrameSet", "FrameSynchronizer", "SyncStats"]


@dataclass(frozen=True, eq=False)
class FrameSet:
    """Frames of one trigger pulse.

    ``frames`` maps camera name -> Frame (only cameras present, in the
    synchroniser's camera order); ``missing`` names the absent cameras;
    ``reason`` is ``"complete"``, ``"skipped"`` or ``"timeout"``; ``wait_ns``
    is how long the set was held (emitting poll time - first frame's arrival;
    0 from ``flush``).
    """

    frame_id: int
    frames: Mapping[str, Frame]
    missing: tuple[str, ...]
    reason: str
    wait_ns: int = 0

    @property
    def complete(self) -> bool:
        return not self.missing


@dataclass(frozen=True)
class SyncStats:
    """Counters since construction (a snapshot)."""

    emitted: int = 0
    complete: int = 0
    incomplete: int = 0
    timeouts: int = 0
    duplicates: int = 0
    late: int = 0
    out_of_order: int = 0
    unknown: int = 0
    overflow: int = 0
    discarded_frames: int = 0
    pending: int = 0
    max_wait_ns: int = 0
    missing_by_camera: dict[str, int] = field(default_factory=dict)
    stopped: tuple[str, ...] = ()


class _Pending:
    __slots__ = ("frame_id", "frames", "first_ns")

    def __init__(self, frame_id: int, first_ns: int | None):
        self.frame_id = frame_id
        self.frames: dict[str, Frame] = {}
        self.first_ns = first_ns


class FrameSynchronizer:
    """Assemble frame sets (see module docstring).

    Parameters
    ----------
    cameras : sequence of str
        Expected camera names.
    timeout_ns : int
        How long a set waits for missing cameras after its first frame.
    stop_after_ns : int, optional
        Silence after which a camera counts as stopped (default ``4 * timeout_ns``).
    max_pending : int
        Bound on sets held at once.
    """

    def __init__(
        self,
        cameras: Sequence[str],
        *,
        timeout_ns: int,
        stop_after_ns: int | None = None,
        max_pending: int = 64,
    ):
        cameras = tuple(cameras)
        if not cameras or len(set(cameras)) != len(cameras):
            raise ValueError(f"cameras must be non-empty and unique, got {cameras!r}")
        if timeout_ns <= 0:
            raise ValueError(f"timeout_ns must be positive, got {timeout_ns}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending}")
        self.cameras = cameras
        self.timeout_ns = int(timeout_ns)
        self.stop_after_ns = int(4 * timeout_ns if stop_after_ns is None else stop_after_ns)
        self.max_pending = int(max_pending)
        self._pending: dict[int, _Pending] = {}
        self._last_emitted: int | None = None
        self._newest = {c: -1 for c in cameras}  # newest frame id per camera
        self._last_seen: dict[str, int | None] = {c: None for c in cameras}  # arrival ns per camera
        self._start_ns: int | None = None
        self._counts = dict.fromkeys(
            ("emitted", "complete", "incomplete", "timeouts", "duplicates", "late", "out_of_order", "unknown", "overflow", "discarded_frames"), 0
        )
        self._missing = dict.fromkeys(cameras, 0)
        self._stopped: set[str] = set()
        self._max_wait_ns = 0

    @property
    def pending(self) -> int:
        """Number of sets held."""
        return len(self._pending)

    @property
    def frames_held(self) -> int:
        return sum(len(p.frames) for p in self._pending.values())

    @property
    def stats(self) -> SyncStats:
        return SyncStats(
            **self._counts,
            pending=len(self._pending),
            max_wait_ns=self._max_wait_ns,
            missing_by_camera=dict(self._missing),
            stopped=tuple(c for c in self.cameras if c in self._stopped),
        )

    def push(self, frame: Frame, now_ns: int | None = None) -> None:
        """Store one frame; ``now_ns`` is its arrival time (default: the time of the next ``poll``)."""
        cam, fid = frame.camera, int(frame.frame_id)
        if cam not in self._newest:
            self._counts["unknown"] += 1
            return
        self._last_seen[cam] = -1 if now_ns is None else int(now_ns)  # -1: stamp at the next poll
        self._stopped.discard(cam)
        if fid == self._newest[cam]:
            self._counts["duplicates"] += 1
            return
        if self._last_emitted is not None and fid <= self._last_emitted:
            self._counts["late"] += 1
            return
        entry = self._pending.get(fid)
        if entry is not None and cam in entry.frames:
            self._counts["duplicates"] += 1
            return
        if fid < self._newest[cam]:
            self._counts["out_of_order"] += 1
        else:
            self._newest[cam] = fid
        if entry is None:
            entry = self._pending[fid] = _Pending(fid, None if now_ns is None else int(now_ns))
            if len(self._pending) > self.max_pending:
                oldest = self._pending.pop(min(self._pending))
                self._last_emitted = oldest.frame_id
                self._counts["overflow"] += 1
                self._counts["discarded_frames"] += len(oldest.frames)
                if oldest is entry:
                    self._counts["discarded_frames"] += 1
                    return
        entry.frames[cam] = frame

    def poll(self, now_ns: int) -> list[FrameSet]:
        """Sets ready at ``now_ns``, in frame-id order."""
        now_ns = int(now_ns)
        if self._start_ns is None:
            self._start_ns = now_ns
        for entry in self._pending.values():
            if entry.first_ns is None:
                entry.first_ns = now_ns
        for cam, seen in self._last_seen.items():
            if seen == -1:
                self._last_seen[cam] = seen = now_ns
            since = self._start_ns if seen is None else seen
            if now_ns - since > self.stop_after_ns:
                self._stopped.add(cam)
        out: list[FrameSet] = []
        for fid in sorted(self._pending):
            entry = self._pending[fid]
            missing = [c for c in self.cameras if c not in entry.frames]
            waiting = [c for c in missing if self._newest[c] <= fid and c not in self._stopped]
            if not missing:
                reason = "complete"
            elif not waiting:
                reason = "skipped"
            elif now_ns - entry.first_ns >= self.timeout_ns:
                reason = "timeout"
            else:
                break
            del self._pending[fid]
            out.append(self._emit(entry, tuple(missing), reason, now_ns - entry.first_ns))
        return out

    def flush(self) -> list[FrameSet]:
        """Emit every pending set now (end of stream), incomplete ones as ``timeout``."""
        out = []
        for fid in sorted(self._pending):
            entry = self._pending.pop(fid)
            missing = tuple(c for c in self.cameras if c not in entry.frames)
            out.append(self._emit(entry, missing, "timeout" if missing else "complete"))
        return out

    def _emit(self, entry: _Pending, missing: tuple[str, ...], reason: str, wait_ns: int = 0) -> FrameSet:
        self._last_emitted = entry.frame_id
        self._max_wait_ns = max(self._max_wait_ns, wait_ns)
        self._counts["emitted"] += 1
        self._counts["complete" if not missing else "incomplete"] += 1
        if reason == "timeout":
            self._counts["timeouts"] += 1
        for c in missing:
            self._missing[c] += 1
        frames = {c: entry.frames[c] for c in self.cameras if c in entry.frames}
        return FrameSet(entry.frame_id, frames, missing, reason, wait_ns)
