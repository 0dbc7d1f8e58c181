"""Which frame ids are plausible now: the wire's guard against far-future (and far-past) ids.

Frame ids are trigger pulses, so they advance at most at the trigger's rate.  A
:class:`FrameIdWindow` follows one id stream (one camera's frames or have notices): its *reference* is
the newest id accepted and when.  An id is accepted when it is no further ahead than the reference
plus what the trigger can have produced since (``rate_hz`` × elapsed, plus ``ahead_s`` of margin and
``slack`` frames), and no further behind than ``behind`` frames.  An id further behind is a
*renumbering* (a restarted trigger or replay loop): it is accepted and becomes the reference, at most
once per ``restart_holdoff_s``, and only once the numbering it replaces has stopped (no id advanced it
for ``restart_holdoff_s``) or was never confirmed (fewer than ``confirm`` ids advanced it: a hostile
first id is overruled by the camera's own) — so a peer sending ids 10^12 cannot move a live studio's
demands, and one sending ids 0 cannot move a running camera's reference back (which would refuse
the camera's real ids as far ahead).
Everything refused is counted (``rejected``).  No I/O, clocks injected.
"""

from __future__ import annotations

__all__ = ["FrameIdWindow", "RateLimit"]


class FrameIdWindow:
    """One stream's plausible frame ids (see the module docstring).

    Parameters
    ----------
    rate_hz : float
        Highest frame rate the trigger can run at (frames per second); ids further ahead than it
        allows are refused.
    ahead_s : float
        Extra time (seconds) of ids allowed ahead of the reference (jitter, a late first message).
    behind : int
        Frames an id may lag the reference before it counts as a renumbering.
    slack : int
        Frames allowed ahead in any case.
    restart_holdoff_s : float
        Shortest time between two accepted renumberings, and the silence after which a confirmed
        numbering counts as stopped (seconds).
    confirm : int
        Ids that must advance a numbering before a renumbering has to wait for it to stop.
    """

    def __init__(self, *, rate_hz: float = 240.0, ahead_s: float = 2.0, behind: int = 256, slack: int = 64,
                 restart_holdoff_s: float = 1.0, confirm: int = 3) -> None:
        if not rate_hz > 0 or ahead_s < 0 or behind < 0 or slack < 0 or restart_holdoff_s < 0:
            raise ValueError("FrameIdWindow: rate_hz > 0 and non-negative bounds are needed")
        self.rate_hz, self.ahead_s, self.behind, self.slack = float(rate_hz), float(ahead_s), int(behind), int(slack)
        self.restart_holdoff_s, self.confirm = float(restart_holdoff_s), int(confirm)
        self._ref: tuple[int, float] | None = None
        self._advances = 0  # ids that advanced the current numbering
        self._last_restart = float("-inf")
        self.accepted = self.rejected = self.restarts = self.stale = 0

    def upper(self, now_s: float) -> int | None:
        """The highest id accepted at ``now_s`` (None before the first id)."""
        if self._ref is None:
            return None
        fid, t = self._ref
        return fid + int(self.rate_hz * (max(0.0, now_s - t) + self.ahead_s)) + self.slack

    def plausible(self, frame_id: int, now_s: float) -> bool:
        """Whether ``frame_id`` would be accepted, without counting or moving the reference."""
        if self._ref is None:
            return frame_id >= 0
        if frame_id < 0 or frame_id > self.upper(now_s):
            return False
        if frame_id >= self._ref[0] - self.behind:
            return True
        replaceable = self._advances < self.confirm or now_s - self._ref[1] >= self.restart_holdoff_s
        return replaceable and now_s - self._last_restart >= self.restart_holdoff_s

    def accept(self, frame_id: int, now_s: float) -> bool:
        """Check ``frame_id``; True (and the reference follows it) if plausible, else counted in ``rejected``."""
        frame_id = int(frame_id)
        if not self.plausible(frame_id, now_s):
            self.rejected += 1
            return False
        if self._ref is not None and frame_id < self._ref[0] - self.behind:
            self.restarts += 1
            self._last_restart = now_s
            self._ref, self._advances = (frame_id, now_s), 0
        elif self._ref is None or frame_id >= self._ref[0]:
            self._advances += self._ref is None or frame_id > self._ref[0]
            self._ref = (frame_id, now_s)
        self.accepted += 1
        return True

    def filter(self, frame_ids, now_s: float) -> tuple[int, ...]:
        """The plausible ids of one notice (its newest sets the reference; the others judged against it).

        An id more than ``behind`` below the newest id accepted from the same notice is stale (an old
        frame still held), not a renumbering: it is left out (counted in ``stale``) and never moves
        the reference back."""
        kept: list[int] = []
        for f in sorted({int(f) for f in frame_ids}, reverse=True):
            if kept and f < kept[0] - self.behind:
                self.stale += 1
            elif self.accept(f, now_s):
                kept.append(f)
        return tuple(sorted(kept))


class RateLimit:
    """A token bucket: at most ``rate_hz`` events per second on average, ``burst`` at once.

    Parameters
    ----------
    rate_hz : float
        Sustained events per second.
    burst : int
        Events allowed back to back.
    """

    def __init__(self, rate_hz: float, burst: int) -> None:
        if not rate_hz > 0 or burst < 1:
            raise ValueError("RateLimit: rate_hz > 0 and burst >= 1 are needed")
        self.rate_hz, self.burst = float(rate_hz), int(burst)
        self._tokens, self._t = float(burst), None
        self.limited = 0

    def allow(self, now_s: float) -> bool:
        """Take one token at ``now_s``; False (counted in ``limited``) when the bucket is empty."""
        if self._t is not None:
            self._tokens = min(self.burst, self._tokens + (now_s - self._t) * self.rate_hz)
        self._t = now_s
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        self.limited += 1
        return False
