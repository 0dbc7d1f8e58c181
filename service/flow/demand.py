"""Live mode: the tracker pulls, segmentation follows.

Every camera frame reaches its host's segment worker, which keeps the newest few of each camera
*undecoded* in a :class:`FrameRing` and announces the ids it holds (``HaveMessage`` on
``cam/<cam>/have``).  The track worker's :class:`DemandPlanner` picks the frame id to fit next from
those notices — the newest id held by the most live cameras — and demands it (``DemandMessage`` on
``demand/track``); segment workers decode and segment that frame only.  So every camera segments the
same frame id (sets complete), the CPU goes to frames the tracker can take, and the tracker demands
the next set before fitting the current one, so segmentation of one set overlaps the fit of the
previous one.  No I/O here (clocks injected); the zenoh wiring is in :mod:`service.workers.segment` and :mod:`service.workers.track`.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Callable

from service.flow.window import FrameIdWindow, RateLimit
from service.wire.messages import MAX_BYTES, TYPE_FRAME, MessageError, meta_int, unpack_message, check_name

RING_MAX_BYTES = 32 * 1024 * 1024  # bytes one camera's FrameRing holds at most (frames as received)
FRAME_RATE_LIMIT_HZ = 480.0  # frames a ring takes per second at most (twice the fastest trigger)
HAVE_RATE_LIMIT_HZ = 200.0  # have notices per camera per second the planner takes at most
RATE_BURST = 64  # messages a key may deliver back to back (a backlog after a 2 s stall at 30 fps)


def frame_header(data: bytes) -> tuple[str, int]:
    """``(camera, frame_id)`` of a FrameMessage's bytes: header, sizes and meta validated, the
    pixels left alone (they are validated by ``FrameMessage.from_bytes`` when demanded)."""
    meta, _ = unpack_message(data, TYPE_FRAME, MAX_BYTES)
    return check_name(meta.get("camera")), meta_int(meta, "frame_id")


class FrameRing:
    """The newest ``size`` frames of one camera as received (bytes + sender time) and the frame ids
    demanded of it.  Filled from zenoh's callback thread, read by the camera's segment thread; all
    methods are thread-safe (``cv`` may be shared to wait on several rings)."""

    def __init__(self, camera: str, *, size: int = 8, max_demands: int = 4,
                 cv: threading.Condition | None = None, max_bytes: int = RING_MAX_BYTES,
                 window: FrameIdWindow | None = None, rate: RateLimit | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.camera, self.size = check_name(camera), max(1, int(size))
        self.max_bytes, self._bytes, self._clock = int(max_bytes), 0, clock
        self.window = window if window is not None else FrameIdWindow()
        self.rate = rate if rate is not None else RateLimit(FRAME_RATE_LIMIT_HZ, burst=RATE_BURST)
        self._frames: collections.OrderedDict[int, tuple[bytes, int | None]] = collections.OrderedDict()
        self._demands: collections.deque[tuple[int, float]] = collections.deque(maxlen=max(1, int(max_demands)))
        self.cv = cv if cv is not None else threading.Condition()
        self._changed = False
        self.received = self.bad = self.evicted = 0
        self.skipped = 0  # frames older than a demand: the tracker went past them
        self.rejected = 0  # far-future/far-past ids, oversized or over-rate frames, implausible demands

    def put(self, data: bytes, sent_ns: int | None) -> int | None:
        """Keep one received frame (its header validated); returns its id, or None when it was
        refused (counted in ``rejected``): larger than ``max_bytes``, over the rate limit, or an id
        outside the camera's plausible window.  A renumbering (see ``FrameIdWindow``) drops the frames
        held, which will never be demanded (counted in ``skipped``).  MessageError if the header is bad or names another
        camera.  The frames held never exceed ``size`` frames nor ``max_bytes`` bytes."""
        camera, fid = frame_header(data)
        if camera != self.camera:
            raise MessageError(f"frame of camera {camera} on camera {self.camera}'s key")
        now = self._clock()
        with self.cv:
            restarts = self.window.restarts
            if len(data) > self.max_bytes or not self.rate.allow(now) or not self.window.accept(fid, now):
                self.rejected += 1
                return None
            if self.window.restarts != restarts:  # renumbered: the frames held are of the old numbering
                self._drop_older(float("inf"))
            old = self._frames.pop(fid, None)
            if old is not None:
                self._bytes -= len(old[0])
            self._frames[fid] = (data, sent_ns)
            self._bytes += len(data)
            while len(self._frames) > self.size or self._bytes > self.max_bytes:  # arrival order
                _, (gone, _) = self._frames.popitem(last=False)
                self._bytes -= len(gone)
                self.evicted += 1
            self.received += 1
            self._changed = True
            self.cv.notify_all()
        return fid

    def demand(self, frame_id: int, now_s: float) -> bool:
        """The tracker wants ``frame_id`` (kept until taken, skipped or expired).  A demand for an id
        this camera cannot have yet (beyond its window: no frame received, or far ahead of the
        newest) is refused (False, counted in ``rejected``) so it cannot push real demands out."""
        with self.cv:
            upper = self.window.upper(self._clock())
            if upper is None or not 0 <= frame_id <= upper:
                self.rejected += 1
                return False
            if all(f != frame_id for f, _ in self._demands):
                self._demands.append((int(frame_id), now_s))
            self.cv.notify_all()
        return True

    def busy(self) -> bool:
        """Whether there is work now: a new frame to announce, or a demand that can be resolved
        without waiting (held, or a newer frame is) — call with ``cv`` held (``cv.wait_for``)."""
        if self._changed:
            return True
        if not self._demands:
            return False
        fid = self._demands[0][0]
        return fid in self._frames or any(f > fid for f in self._frames)

    def take_news(self) -> tuple[int, ...] | None:
        """The ids held (oldest first) if a frame arrived since the last call, else None."""
        with self.cv:
            if not self._changed:
                return None
            self._changed = False
            return tuple(self._frames)

    def newest(self) -> tuple[int, bytes, int | None] | None:
        """``(frame_id, data, sent_ns)`` of the newest frame held, or None."""
        with self.cv:
            if not self._frames:
                return None
            fid = next(reversed(self._frames))
            return (fid,) + self._frames[fid]

    def next_demanded(self, now_s: float, *, wait_s: float) -> tuple[list[int], tuple | None]:
        """Resolve the oldest demand: ``(missed_ids, (frame_id, data, sent_ns) or None)``.

        A demanded frame that is held is taken out of the ring; one that is not held while a newer
        frame is (skipped or evicted), or that has not arrived within ``wait_s``, is missed; one not
        arrived yet is kept waiting (None).  Frames older than a demand taken or missed are dropped
        (counted in ``skipped``): the tracker demands ever newer ids, so they would only sit in the
        ring and in its have notices."""
        missed: list[int] = []
        with self.cv:
            while self._demands:
                fid, since = self._demands[0]
                if fid in self._frames:
                    self._demands.popleft()
                    data, sent_ns = self._frames.pop(fid)
                    self._bytes -= len(data)
                    self._drop_older(fid)
                    return missed, (fid, data, sent_ns)
                if any(f > fid for f in self._frames) or now_s - since > wait_s:
                    self._demands.popleft()
                    missed.append(fid)
                    self._drop_older(fid)
                    continue
                break
        return missed, None

    def _drop_older(self, frame_id: float) -> None:
        """Drop the frames held with ids below ``frame_id`` (call with ``cv`` held)."""
        for f in [f for f in self._frames if f < frame_id]:
            self._bytes -= len(self._frames.pop(f)[0])
            self.skipped += 1

    def __len__(self) -> int:
        return len(self._frames)


class DemandPlanner:
    """Tracker side: which frame id to demand next, from the cameras' have notices.

    - A camera is *live* when a notice came within ``absent_after_s`` (a dead camera or segment
      worker drops out and the sets go on without it; it rejoins with its next notice).
    - Nothing is demanded until every configured camera was heard or ``startup_grace_s`` passed
      since the first notice (start-up sets are not demanded half-empty).
    - One demand is outstanding at a time: the next one goes out when the demanded set is released
      (:meth:`released`, the tracker then fits it while the next is segmented) or after
      ``demand_timeout_s`` without it (a lost demand, a frame no camera had; counted in ``timeouts``)
      unless ``hold(frame_id)`` says its set is still being assembled.
    - The frame demanded is the newest id (above the last demanded) that every live camera holds.
      When none is held by all (a frame lost on its way to one camera's segment worker), up to
      ``partial_wait_s`` is given for a newer one; then the id held by the most cameras, the newest
      of those, is demanded (the set goes on without the camera that lacks it).
    - A camera whose ids go back by more than ``restart_gap`` restarted its numbering: ids above its
      new ones count as new again (``restarts``).
    - The wire is not trusted: each camera's ids are checked against its :class:`FrameIdWindow`
      (ids beyond what a trigger at ``rate_hz`` can have produced are dropped, counted in
      ``rejected``; a camera's first notice may not run ahead of the cameras already heard), and a
      camera's notices are rate-limited (``HAVE_RATE_LIMIT_HZ``), so a peer announcing frame 10^12
      or flooding notices cannot redirect the demands.
    """

    def __init__(self, cameras: tuple[str, ...], *, absent_after_s: float = 0.5, startup_grace_s: float = 0.5,
                 demand_timeout_s: float = 0.25, partial_wait_s: float = 0.1, restart_gap: int = 8,
                 remember: int = 16, rate_hz: float = 240.0) -> None:
        if not cameras:
            raise ValueError("cameras: at least one camera name is needed")
        self.cameras = tuple(cameras)
        self.absent_after_s, self.startup_grace_s = float(absent_after_s), float(startup_grace_s)
        self.demand_timeout_s, self.restart_gap = float(demand_timeout_s), int(restart_gap)
        self.partial_wait_s = float(partial_wait_s)
        self._partial_since: float | None = None
        self._held: dict[str, frozenset[int]] = {}
        self._newest: dict[str, int] = {}
        self._heard: dict[str, float] = {}
        self._first_heard: float | None = None
        self._recent: collections.deque[int] = collections.deque(maxlen=max(1, int(remember)))
        self.outstanding: tuple[int, float] | None = None
        self.last_demanded = -1
        self.demands = self.timeouts = self.restarts = self.unknown = 0
        self.rate_hz = float(rate_hz)
        self._windows: dict[str, FrameIdWindow] = {}
        self._limits: dict[str, RateLimit] = {}
        self.limited = 0  # notices over a camera's rate limit
        self.early_rejected = 0  # ids of a camera's first notice beyond every other camera's window

    def have(self, camera: str, frame_ids: tuple[int, ...], now_s: float) -> bool:
        """Record a have notice; False (counted in ``unknown``) for a camera not configured."""
        if camera not in self.cameras:
            self.unknown += 1
            return False
        limit = self._limits.setdefault(camera, RateLimit(HAVE_RATE_LIMIT_HZ, burst=RATE_BURST))
        if not limit.allow(now_s):
            self.limited += 1
            return False
        if frame_ids:
            if camera not in self._windows:  # a camera's first notice: no further ahead than the others allow
                uppers = [u for w in self._windows.values() if (u := w.upper(now_s)) is not None]
                if uppers:
                    kept = tuple(f for f in frame_ids if f <= max(uppers))
                    self.early_rejected += len(frame_ids) - len(kept)
                    frame_ids = kept
                    if not frame_ids:
                        return False
            window = self._windows.setdefault(camera, FrameIdWindow(rate_hz=self.rate_hz))
            frame_ids = window.filter(frame_ids, now_s)
            if not frame_ids:  # nothing plausible: not a sign of life either
                return False
        self._heard[camera] = now_s
        if self._first_heard is None:
            self._first_heard = now_s
        self._held[camera] = frozenset(frame_ids)
        if frame_ids:
            newest = max(frame_ids)
            if newest < self._newest.get(camera, -1) - self.restart_gap:  # renumbered
                self.restarts += 1
                self.last_demanded = min(self.last_demanded, newest - 1)
            self._newest[camera] = newest
        return True

    @property
    def rejected(self) -> int:
        """Frame ids of have notices refused as implausible (beyond a camera's window), and notices
        over the rate limit."""
        return sum(w.rejected for w in self._windows.values()) + self.limited + self.early_rejected

    def live(self, now_s: float) -> tuple[str, ...]:
        """Cameras heard from within ``absent_after_s``."""
        return tuple(c for c in self.cameras if c in self._heard and now_s - self._heard[c] <= self.absent_after_s)

    def next_demand(self, now_s: float, *, hold: Callable[[int], bool] = lambda fid: False) -> int | None:
        """The frame id to demand now (and it becomes the outstanding demand), or None."""
        if self.outstanding is not None:
            fid, since = self.outstanding
            if now_s - since <= self.demand_timeout_s or hold(fid):
                return None
            self.timeouts += 1
            self.outstanding = None
        if self._first_heard is None or (len(self._heard) < len(self.cameras)
                                         and now_s - self._first_heard < self.startup_grace_s):
            return None
        live = self.live(now_s)
        counts: collections.Counter[int] = collections.Counter(
            f for c in live for f in self._held.get(c, ()) if f > self.last_demanded)
        if not counts:
            self._partial_since = None
            return None
        fid = max(counts, key=lambda f: (counts[f], f))
        if counts[fid] < len(live):  # a frame lost on its way to one camera's worker: a newer one may come
            if self._partial_since is None:
                self._partial_since = now_s
            if now_s - self._partial_since < self.partial_wait_s:
                return None
        self._partial_since = None
        self.outstanding, self.last_demanded = (fid, now_s), fid
        self._recent.append(fid)
        self.demands += 1
        return fid

    def released(self, frame_id: int) -> None:
        """The set ``frame_id`` was released: a demand up to it is no longer outstanding."""
        if self.outstanding is not None and self.outstanding[0] <= frame_id:
            self.outstanding = None

    def wanted(self, frame_id: int) -> bool:
        """Whether ``frame_id`` was demanded recently (chamfers of other ids are not assembled)."""
        return frame_id in self._recent
