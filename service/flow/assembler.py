"""Assemble per-camera messages into frame sets by frame id (clock injected, no I/O).

Rules (``cameras`` = the configured camera names):

- ``live``: a camera is *present* if it delivered anything (or was :meth:`seen` alive) within ``absent_after_s``; a camera
  that stops lowers the quality of later sets (it is left out of them), not availability; when it
  delivers again it rejoins at once.  ``lossless``: every configured camera is waited for.
- Set ``k`` is *complete* when every present camera delivered ``k``, or — frames of one camera
  arrive in order — delivered a later id (it skipped ``k``).  A set older than ``timeout_s`` is
  released with the cameras it has.
- ``live``: the newest complete (or timed-out) set is released; older pending sets are dropped
  and counted in ``stale``; messages for ids at or below the last released one are dropped
  (``late``).  ``lossless``: sets are released strictly in frame-id order, never dropped.
- ``live``: frame ids of one camera increase; a camera whose id goes back by more than
  ``restart_gap`` frames (a few back is just a late message) has restarted its numbering (e.g. the trigger box was reopened): its new ids are accepted, ids already released
  above them stop counting as "released", and pending sets of the old numbering above them are
  dropped (counted in ``restarts``) — otherwise every later frame would be ``late`` for good.
- Memory is bounded (ids come from the network): beyond ``max_pending`` pending sets the oldest
  is discarded (counted in ``overflow``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class FrameSet(Generic[T]):
    """One frame id's messages: ``items`` camera -> message; ``missing`` configured cameras absent."""

    frame_id: int
    items: dict[str, T]
    missing: tuple[str, ...]
    first_arrival_s: float
    timed_out: bool = False


@dataclass
class _Pending:
    first_arrival_s: float
    items: dict = field(default_factory=dict)


class FrameSetAssembler(Generic[T]):
    def __init__(self, cameras: tuple[str, ...], *, mode: str = "live", timeout_s: float = 0.08,
                 absent_after_s: float = 1.0, restart_gap: int = 8, max_pending: int = 256) -> None:
        if mode not in ("live", "lossless"):
            raise ValueError(f"mode must be live or lossless, got {mode!r}")
        if not cameras:
            raise ValueError("cameras: at least one camera name is needed")
        self.cameras, self.mode = tuple(cameras), mode
        self.timeout_s, self.absent_after_s = float(timeout_s), float(absent_after_s)
        self.restart_gap, self.max_pending = int(restart_gap), max(1, int(max_pending))
        self._pending: dict[int, _Pending] = {}
        self._latest_id: dict[str, int] = {}
        self._last_seen: dict[str, float] = {}
        self.last_released = -1
        self._t_start: float | None = None
        self.stale = self.late = self.unknown = self.restarts = self.overflow = 0

    def add(self, camera: str, frame_id: int, item: T, now_s: float) -> None:
        """Record one camera's message for ``frame_id`` received at ``now_s``."""
        if camera not in self.cameras:
            self.unknown += 1
            return
        self._last_seen[camera] = now_s
        if self._t_start is None:
            self._t_start = now_s
        if self.mode == "live" and frame_id < self._latest_id.get(camera, -1) - self.restart_gap:  # renumbered
            self.restarts += 1
            self._latest_id[camera] = frame_id
            self.last_released = min(self.last_released, frame_id - 1)
            for fid in [f for f in self._pending if f > frame_id]:
                del self._pending[fid]
        self._latest_id[camera] = max(self._latest_id.get(camera, -1), frame_id)
        if frame_id <= self.last_released:
            self.late += 1
            return
        self._pending.setdefault(frame_id, _Pending(now_s)).items[camera] = item
        if len(self._pending) > self.max_pending:
            del self._pending[min(self._pending)]
            self.overflow += 1

    def seen(self, camera: str, now_s: float) -> None:
        """``camera`` is alive at ``now_s`` without a message for a set (live mode on demand: its
        segment worker's have notice; the camera then counts as present while its chamfer is due)."""
        if camera in self.cameras:
            self._last_seen[camera] = max(now_s, self._last_seen.get(camera, now_s))
            if self._t_start is None:
                self._t_start = now_s

    def present(self, now_s: float) -> tuple[str, ...]:
        """Cameras heard from within ``absent_after_s`` (never-heard ones count during the first
        ``absent_after_s`` after the first message, so start-up sets are not released half-empty)."""
        default = self._t_start if self._t_start is not None else now_s
        return tuple(c for c in self.cameras if now_s - self._last_seen.get(c, default) <= self.absent_after_s)

    def _complete(self, fid: int, present: tuple[str, ...]) -> bool:
        items = self._pending[fid].items
        return all(c in items or self._latest_id.get(c, -1) > fid for c in present)

    def _release(self, fid: int, now_s: float, timed_out: bool) -> FrameSet[T]:
        p = self._pending.pop(fid)
        self.last_released = fid
        missing = tuple(c for c in self.cameras if c not in p.items)
        return FrameSet(fid, dict(p.items), missing, p.first_arrival_s, timed_out)

    def pop_ready(self, now_s: float) -> list[FrameSet[T]]:
        """Sets ready at ``now_s`` (live: at most one, the newest ready)."""
        out: list[FrameSet[T]] = []
        if self.mode == "lossless":  # every configured camera is waited for (up to timeout_s)
            present = self.cameras
            while self._pending:
                fid = min(self._pending)
                timed_out = now_s - self._pending[fid].first_arrival_s > self.timeout_s
                if not (self._complete(fid, present) or timed_out):
                    break
                out.append(self._release(fid, now_s, timed_out and not self._complete(fid, present)))
            return out
        present = self.present(now_s)
        ready = [fid for fid in self._pending if self._complete(fid, present)
                 or now_s - self._pending[fid].first_arrival_s > self.timeout_s]
        if not ready:
            return out
        newest = max(ready)
        for fid in [f for f in self._pending if f < newest]:
            del self._pending[fid]
            self.stale += 1
        out.append(self._release(newest, now_s, not self._complete(newest, present)))
        return out

    def next_deadline(self) -> float | None:
        """Time (same clock as ``now_s``) when the oldest pending set times out, or None."""
        if not self._pending:
            return None
        return min(p.first_arrival_s for p in self._pending.values()) + self.timeout_s

    def is_pending(self, frame_id: int) -> bool:
        """Whether a set with this id is waiting to be released."""
        return frame_id in self._pending

    def __len__(self) -> int:
        return len(self._pending)

    def stats(self) -> dict[str, Any]:
        return {"pending": len(self._pending), "stale_sets": self.stale, "late": self.late,
                "restarts": self.restarts, "overflow": self.overflow}
