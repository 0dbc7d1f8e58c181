"""Frame-set assembly: per-camera items (frames, chamfer images, ...) -> sets by frame id.

Pure and single-threaded: ``add(camera, frame_id, item, now)`` stores, ``pop_ready(now)`` returns
the sets that are ready.  Time comes only from the caller (``now`` on the same clock, in any unit,
for every call; :class:`FrameSynchronizer` is the nanosecond face over ``capture.sources.Frame``).

Rules (``cameras`` = the expected camera names):

- A camera is *present* if it delivered anything (or was :meth:`~FrameSetAssembler.seen`) within
  ``absent_after`` (never-heard ones count from the first item on); sets do not wait for an absent
  camera, and it rejoins when it delivers again.  ``absent_after=None``: every camera is waited for.
- Set ``k`` is *complete* when every present camera delivered ``k``, or *skipped* it: frames of one
  camera arrive in order, so a camera that delivered a later id dropped ``k``.  A set whose first item
  arrived ``timeout`` ago is released with what it has (reason ``timeout``).
- ``lossless`` mode: sets leave strictly in frame-id order, never dropped.  ``live`` mode (newest
  wins): the newest ready set is released; older pending sets are dropped (``stale``); a camera whose
  id goes back by more than ``restart_gap`` has restarted its numbering (e.g. the trigger box was
  reopened): its new ids are accepted and pending sets of the old numbering above them dropped
  (``restarts``); otherwise every later frame would be late for good.

Bad input is counted, never raised: a *duplicate* (camera, id) is dropped (the first is kept); a
*late* item (its id was already released) is dropped; an *out-of-order* item (id below that camera's
newest) is counted and still used if its set is pending; an item of an unknown camera is dropped.
Memory is bounded (ids may come from the network): beyond ``max_pending`` pending sets the oldest is
discarded (sets counted in ``overflow``, their items in ``discarded_frames``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Generic, Mapping, Sequence, TypeVar

from capture.sources import Frame

__all__ = ["MODES", "FrameSet", "FrameSetAssembler", "FrameSynchronizer", "SyncStats"]

T = TypeVar("T")
MODES = ("live", "lossless")
_COUNTERS = ("emitted", "complete", "incomplete", "timeouts", "duplicates", "late", "out_of_order", "unknown",
             "overflow", "discarded_frames", "stale", "restarts")


@dataclass(frozen=True, eq=False)
class FrameSet(Generic[T]):
    """The items of one frame id.

    Attributes
    ----------
    frame_id : int
    items : mapping
        Camera name -> item, cameras present only, in the assembler's camera order.
    missing : tuple of str
        Expected cameras absent from ``items``.
    reason : {"complete", "skipped", "timeout"}
        Why it was released (``skipped``: every missing camera moved on or is absent).
    first_arrival : float
        When its first item arrived (the caller's clock).
    wait : float
        Release time minus ``first_arrival`` (0 from ``flush``).
    """

    frame_id: int
    items: Mapping[str, T]
    missing: tuple[str, ...]
    reason: str
    first_arrival: float = 0
    wait: float = 0

    @property
    def complete(self) -> bool:
        """Every expected camera delivered."""
        return not self.missing

    @property
    def timed_out(self) -> bool:
        """Released by the timeout while a present camera was still due."""
        return self.reason == "timeout"

    @property
    def frames(self) -> Mapping[str, T]:
        """``items`` (for sets of ``Frame``)."""
        return self.items

    @property
    def wait_ns(self) -> int:
        """``wait`` as an integer (for the nanosecond clock of :class:`FrameSynchronizer`)."""
        return int(self.wait)


class _Pending:
    __slots__ = ("frame_id", "items", "first")

    def __init__(self, frame_id: int, first: float | None):
        self.frame_id, self.items, self.first = frame_id, {}, first  # first None: stamped at the next poll


class FrameSetAssembler(Generic[T]):
    """Assemble per-camera items into frame sets (rules in the module docstring).

    Parameters
    ----------
    cameras : sequence of str
        Expected camera names (unique).
    mode : {"live", "lossless"}
        Newest wins, or every set in frame-id order.
    timeout_s : float
        How long a set waits for present cameras after its first item.
    absent_after_s : float or None
        Silence after which a camera is absent (None: never).

    Times are seconds for the service's monotonic clock, but no unit is assumed: any clock works
    if every time given (``now_s`` too) uses it (:class:`FrameSynchronizer` uses nanoseconds).
    restart_gap : int
        ``live``: an id this far below a camera's newest is a restarted numbering.
    max_pending : int
        Bound on sets held at once.
    """

    def __init__(self, cameras: Sequence[str], *, mode: str = "live", timeout_s: float = 0.08,
                 absent_after_s: float | None = 1.0, restart_gap: int = 8, max_pending: int = 256) -> None:
        cameras = tuple(cameras)
        if mode not in MODES:
            raise ValueError(f"mode must be live or lossless, got {mode!r}")
        if not cameras or len(set(cameras)) != len(cameras):
            raise ValueError(f"cameras must be non-empty and unique, got {cameras!r}")
        if not timeout_s > 0:
            raise ValueError(f"timeout must be positive, got {timeout_s}")
        if max_pending < 1:
            raise ValueError(f"max_pending must be >= 1, got {max_pending}")
        self.cameras, self.mode = cameras, mode
        self.timeout_s, self.absent_after_s = timeout_s, absent_after_s
        self.restart_gap, self.max_pending = int(restart_gap), int(max_pending)
        self._pending: dict[int, _Pending] = {}
        self._newest = dict.fromkeys(cameras, -1)  # newest frame id per camera
        self._last_seen: dict[str, float] = {}
        self._unstamped: set[str] = set()  # cameras that delivered since the last poll, time unknown
        self._t_start: float | None = None
        self.last_released = -1
        self.counts = dict.fromkeys(_COUNTERS, 0)
        self.missing_by_camera = dict.fromkeys(cameras, 0)
        self.max_wait = 0

    # counters under the names the track worker reports
    stale = property(lambda self: self.counts["stale"])
    late = property(lambda self: self.counts["late"])
    unknown = property(lambda self: self.counts["unknown"])
    restarts = property(lambda self: self.counts["restarts"])
    overflow = property(lambda self: self.counts["overflow"])

    def add(self, camera: str, frame_id: int, item: T, now_s: float | None) -> None:
        """Store one camera's item for ``frame_id``, arrived at ``now_s`` (None: at the next ``pop_ready``)."""
        fid = int(frame_id)
        if camera not in self._newest:
            self.counts["unknown"] += 1
            return
        if now_s is None:
            self._unstamped.add(camera)
        else:
            self.seen(camera, now_s)
        restarted = self.mode == "live" and fid < self._newest[camera] - self.restart_gap
        if restarted:  # renumbered: ids released or pending above fid belong to the old numbering
            self.counts["restarts"] += 1
            self._newest[camera] = fid
            self.last_released = min(self.last_released, fid - 1)
            for old in [f for f in self._pending if f > fid]:
                del self._pending[old]
        elif fid == self._newest[camera]:
            self.counts["duplicates"] += 1
            return
        if fid <= self.last_released:
            self.counts["late"] += 1
            return
        entry = self._pending.get(fid)
        if entry is not None and camera in entry.items:
            self.counts["duplicates"] += 1
            return
        if fid < self._newest[camera]:
            self.counts["out_of_order"] += 1
        else:
            self._newest[camera] = fid
        if entry is None:
            entry = self._pending[fid] = _Pending(fid, now_s)
            if len(self._pending) > self.max_pending:
                oldest = self._pending.pop(min(self._pending))
                self.last_released = max(self.last_released, oldest.frame_id)
                self.counts["overflow"] += 1
                self.counts["discarded_frames"] += len(oldest.items) + (oldest is entry)
                if oldest is entry:
                    return
        entry.items[camera] = item

    def seen(self, camera: str, now_s: float) -> None:
        """``camera`` is alive at ``now_s`` without an item (live mode on demand: its segment worker's
        have notice; the camera then counts as present while its item is due)."""
        if camera in self._newest:
            self._last_seen[camera] = max(now_s, self._last_seen.get(camera, now_s))
            if self._t_start is None:
                self._t_start = now_s

    def present(self, now_s: float, absent_after_s: float | None = ...) -> tuple[str, ...]:
        """Cameras heard from within ``absent_after_s`` (default: the assembler's; never-heard ones
        count during the first ``absent_after_s`` after the first item, so start-up sets are not
        released half-empty)."""
        limit = self.absent_after_s if absent_after_s is ... else absent_after_s
        if limit is None:
            return self.cameras
        default = self._t_start if self._t_start is not None else now_s
        return tuple(c for c in self.cameras
                     if c in self._unstamped or now_s - self._last_seen.get(c, default) <= limit)

    def _stamp(self, now_s: float) -> None:
        """Arrivals of unknown time (``add(..., None)``) happened at ``now_s``."""
        for entry in self._pending.values():
            if entry.first is None:
                entry.first = now_s
        for camera in self._unstamped:
            self.seen(camera, now_s)
        self._unstamped.clear()

    def _reason(self, fid: int, present: tuple[str, ...], now_s: float) -> str | None:
        """Why set ``fid`` may leave now, or None if it must wait."""
        entry = self._pending[fid]
        missing = [c for c in self.cameras if c not in entry.items]
        if not missing:
            return "complete"
        if all(c not in present or self._newest[c] > fid for c in missing):
            return "skipped"
        return "timeout" if now_s - entry.first >= self.timeout_s else None

    def _release(self, fid: int, reason: str, wait: float) -> FrameSet[T]:
        entry = self._pending.pop(fid)
        self.last_released = fid
        missing = tuple(c for c in self.cameras if c not in entry.items)
        self.max_wait = max(self.max_wait, wait)
        self.counts["emitted"] += 1
        self.counts["complete" if not missing else "incomplete"] += 1
        self.counts["timeouts"] += reason == "timeout"
        for c in missing:
            self.missing_by_camera[c] += 1
        items = {c: entry.items[c] for c in self.cameras if c in entry.items}
        return FrameSet(fid, items, missing, reason, entry.first, wait)

    def pop_ready(self, now_s: float) -> list[FrameSet[T]]:
        """Sets ready at ``now_s``: lossless, in frame-id order; live, at most one (the newest ready)."""
        self._stamp(now_s)
        present = self.present(now_s)
        out: list[FrameSet[T]] = []
        if self.mode == "lossless":
            for fid in sorted(self._pending):
                reason = self._reason(fid, present, now_s)
                if reason is None:
                    break
                out.append(self._release(fid, reason, now_s - self._pending[fid].first))
            return out
        ready = {fid: r for fid in self._pending if (r := self._reason(fid, present, now_s)) is not None}
        if ready:
            newest = max(ready)
            for fid in [f for f in self._pending if f < newest]:
                del self._pending[fid]
                self.counts["stale"] += 1
            out.append(self._release(newest, ready[newest], now_s - self._pending[newest].first))
        return out

    def flush(self) -> list[FrameSet[T]]:
        """Release every pending set now, in frame-id order (end of stream); incomplete ones as ``timeout``."""
        out = []
        for fid in sorted(self._pending):
            complete = all(c in self._pending[fid].items for c in self.cameras)
            out.append(self._release(fid, "complete" if complete else "timeout", 0))
        return out

    def next_deadline(self) -> float | None:
        """When (the caller's clock) the oldest pending set times out, or None."""
        if not self._pending:
            return None
        firsts = [p.first for p in self._pending.values() if p.first is not None]
        return min(firsts) + self.timeout_s if firsts else None

    def is_pending(self, frame_id: int) -> bool:
        """Whether a set with this id is waiting to be released."""
        return frame_id in self._pending

    @property
    def items_held(self) -> int:
        """Items in the pending sets."""
        return sum(len(p.items) for p in self._pending.values())

    def __len__(self) -> int:
        return len(self._pending)

    def stats(self) -> dict[str, Any]:
        """Pending sets and the track worker's counters."""
        return {"pending": len(self._pending), "stale_sets": self.stale, "late": self.late,
                "restarts": self.restarts, "overflow": self.overflow}


@dataclass(frozen=True)
class SyncStats:
    """Counters of a :class:`FrameSynchronizer` since construction (a snapshot)."""

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


class FrameSynchronizer:
    """Frames of N cameras -> frame sets in frame-id order: a lossless :class:`FrameSetAssembler` on
    a nanosecond clock (a frame pushed without a time arrived at the next poll).

    Parameters
    ----------
    cameras : sequence of str
        Expected camera names.
    timeout_ns : int
        How long a set waits for missing cameras after its first frame (ns).
    stop_after_ns : int, optional
        Silence after which a camera counts as stopped (default ``4 * timeout_ns``).
    max_pending : int
        Bound on sets held at once.
    """

    def __init__(self, cameras: Sequence[str], *, timeout_ns: int, stop_after_ns: int | None = None,
                 max_pending: int = 64):
        if timeout_ns <= 0:
            raise ValueError(f"timeout_ns must be positive, got {timeout_ns}")
        self.timeout_ns = int(timeout_ns)
        self.stop_after_ns = int(4 * timeout_ns if stop_after_ns is None else stop_after_ns)
        # the assembler's clock is unit-free: nanoseconds here (integers: exact timeouts)
        self._asm: FrameSetAssembler[Frame] = FrameSetAssembler(
            cameras, mode="lossless", timeout_s=self.timeout_ns, absent_after_s=self.stop_after_ns,
            max_pending=max_pending)
        self.cameras, self.max_pending = self._asm.cameras, self._asm.max_pending
        self._last_poll_ns: int | None = None

    @property
    def pending(self) -> int:
        """Number of sets held."""
        return len(self._asm)

    @property
    def frames_held(self) -> int:
        """Frames in the pending sets."""
        return self._asm.items_held

    @property
    def stats(self) -> SyncStats:
        asm = self._asm
        counts = {k: v for k, v in asm.counts.items() if k in SyncStats.__dataclass_fields__}
        stopped = () if self._last_poll_ns is None else tuple(
            c for c in self.cameras if c not in asm.present(self._last_poll_ns))
        return SyncStats(**counts, pending=len(asm), max_wait_ns=int(asm.max_wait),
                         missing_by_camera=dict(asm.missing_by_camera), stopped=stopped)

    def push(self, frame: Frame, now_ns: int | None = None) -> None:
        """Store one frame; ``now_ns`` is its arrival time (default: the time of the next ``poll``)."""
        self._asm.add(frame.camera, frame.frame_id, frame, None if now_ns is None else int(now_ns))

    def poll(self, now_ns: int) -> list[FrameSet[Frame]]:
        """Sets ready at ``now_ns``, in frame-id order."""
        self._last_poll_ns = int(now_ns)
        return self._asm.pop_ready(int(now_ns))

    def flush(self) -> list[FrameSet[Frame]]:
        """Emit every pending set now (end of stream), incomplete ones as ``timeout``."""
        return self._asm.flush()
