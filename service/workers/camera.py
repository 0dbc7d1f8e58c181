"""The camera worker: read the sources, publish their frames (lossless: within the tracker's credit)."""

from __future__ import annotations

import threading
import time
from typing import Callable, Mapping

import zenoh

from capture.sources import EndOfStream, Source, SourceError, SourceTimeout
from service.wire.bus import (CreditGate, Keys, StatusReporter, attachment_ns, declare_publisher, wait_until_alive,
                              wait_until_matched)
from service.wire.messages import FrameMessage
from service.workers.base import TRACK_CONSUMER, WorkerError, segment_token

__all__ = ["EpochPacer", "CameraWorker", "run_camera_worker"]


class EpochPacer:
    """Live replay pacing shared by all camera workers of a studio.

    A frame with session time ``t`` is due at wall time ``epoch_ns + t``; frames already late by
    more than ``max_late_ns`` are skipped (so a restarted camera worker rejoins at the present, not
    at frame 0), except that a late frame still goes out when none went out for ``max_gap_ns``: a
    host too slow to read the cameras at full rate then streams fewer, late frames instead of none.

    Parameters
    ----------
    epoch_ns : int
        Wall-clock time (ns) at which session time 0 is due.
    max_late_ns, max_gap_ns : int
        Lateness beyond which a frame is skipped; silence after which a late frame goes out anyway.
    wall_ns, sleep : callable
        Wall clock (ns) and sleep (seconds), injected for tests.
    """

    def __init__(self, epoch_ns: int, *, max_late_ns: int = 20_000_000, max_gap_ns: int = 200_000_000,
                 wall_ns: Callable[[], int] = time.time_ns, sleep: Callable[[float], None] = time.sleep) -> None:
        self.epoch_ns, self.max_late_ns, self.max_gap_ns = int(epoch_ns), int(max_late_ns), int(max_gap_ns)
        self._wall_ns, self._sleep = wall_ns, sleep
        self._last_sent_ns: int | None = None

    def __call__(self, timestamp_ns: int) -> bool:
        """Wait until the frame of session time ``timestamp_ns`` is due; False: skip it."""
        due = self.epoch_ns + int(timestamp_ns)
        now = self._wall_ns()
        if now - due > self.max_late_ns:
            starved = self._last_sent_ns is not None and now - self._last_sent_ns >= self.max_gap_ns
            if not starved:
                if self._last_sent_ns is None:  # first frame: count the gap from here
                    self._last_sent_ns = now
                return False
        elif due > now:
            self._sleep((due - now) / 1e9)
        self._last_sent_ns = self._wall_ns()
        return True


class CameraWorker:
    """Read every source round-robin and publish its frames until all end or ``stop``.

    Lossless: frame ``k`` is published only once the tracker acknowledged ``k - window``
    (:class:`~service.wire.bus.CreditGate`) and only once the tracker and a segment worker for each
    camera are alive (``startup_timeout_s``); at the end it returns only once the tracker has
    acknowledged its last frame (closing the session earlier lost the frames still in flight).

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    sources : mapping
        Camera name -> open source (context managers entered by the caller).
    mode : {"live", "lossless"}
    encodings : mapping, optional
        Camera name -> wire encoding (``"raw"`` by default).
    jpeg_quality : int
    window : int
        Lossless: frames in flight before the cameras wait.
    stop : threading.Event
    credit_timeout_s, startup_timeout_s : float
        How long a credit, and the consumers at start-up, are waited for.
    wall_ns : callable () -> int
        Wall clock for the latency attachment.
    component : str
        Status name.
    pace : callable (timestamp_ns) -> bool, optional
        E.g. :class:`EpochPacer`: may sleep; False skips the frame (counted in ``skipped``).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, sources: Mapping[str, Source], *, mode: str = "live",
                 encodings: Mapping[str, str] | None = None, jpeg_quality: int = 90, window: int = 8,
                 stop: threading.Event, credit_timeout_s: float = 600.0, startup_timeout_s: float = 120.0,
                 wall_ns: Callable[[], int] = time.time_ns, component: str = "camera",
                 pace: Callable[[int], bool] | None = None) -> None:
        self.session, self.keys, self.sources, self.mode = session, keys, dict(sources), mode
        self.encodings, self.jpeg_quality = dict(encodings or {}), jpeg_quality
        self.stop, self.credit_timeout_s, self.startup_timeout_s = stop, credit_timeout_s, startup_timeout_s
        self.wall_ns, self.pace = wall_ns, pace
        self.pubs = {name: declare_publisher(session, keys.frame(name), mode=mode) for name in self.sources}
        self.gate = CreditGate(session, keys, (TRACK_CONSUMER,), window=window) if mode == "lossless" else None
        self.status = StatusReporter(session, keys, component)
        self.last_sent: int | None = None

    def run(self) -> dict:
        """Publish until every source ended or ``stop``; returns the counters.

        Raises :class:`WorkerError` when the consumers are not reachable in time, a credit is missing
        for ``credit_timeout_s``, or a source fails (a SourceError other than a timeout or its end).
        """
        try:
            if self.gate is not None and not self._consumers_ready():
                return dict(self.status.counters)
            if not self._loop():
                return dict(self.status.counters)
            if self.gate is not None:
                self._drain()
            self.status.tick(state="finished", force=True)
            return dict(self.status.counters)
        finally:
            self.close()

    def _consumers_ready(self) -> bool:
        """Lossless: nothing may be published before the consumers listen (False: stopped meanwhile)."""
        needed = (TRACK_CONSUMER,) + tuple(segment_token(c) for c in self.sources)
        ready = (wait_until_alive(self.session, self.keys, needed, timeout_s=self.startup_timeout_s, stop=self.stop)
                 and wait_until_matched(self.pubs.values(), timeout_s=self.startup_timeout_s, stop=self.stop))
        if not ready and not self.stop.is_set():
            raise WorkerError(f"lossless: tracker or segment workers {list(needed)} not reachable "
                              f"within {self.startup_timeout_s:g} s")
        return ready

    def _loop(self) -> bool:
        """Round-robin reads until every source ended or ``stop``; False if stopped waiting for a credit."""
        active = dict(self.sources)
        while active and not self.stop.is_set():
            for name, src in list(active.items()):
                try:
                    frame = src.read()
                except SourceTimeout:
                    self.status.count("timeouts")
                    continue
                except EndOfStream:
                    del active[name]
                    continue
                except SourceError as exc:
                    self.status.count("errors")
                    self.status.tick(state="failed", force=True, cameras=len(active) - 1)
                    raise WorkerError(f"camera {name}: {exc}") from exc
                if self.pace is not None and not self.pace(frame.timestamp_ns):
                    self.status.count("skipped")
                    continue
                if self.gate is not None and not self._credit(name, frame.frame_id):
                    return False
                self._publish(name, frame)
            self.status.tick(cameras=len(active))
        return True

    def _credit(self, name: str, frame_id: int) -> bool:
        """Lossless: wait for the credit of ``frame_id`` (False: stopped meanwhile)."""
        if self.gate.wait(frame_id, timeout_s=self.credit_timeout_s, stop=self.stop):
            return True
        if self.stop.is_set():
            return False
        raise WorkerError(f"camera {name}: no credit from the tracker for frame "
                          f"{frame_id} within {self.credit_timeout_s:g} s")

    def _publish(self, name: str, frame) -> None:
        wire = FrameMessage.wire_of_image(name, frame.frame_id, frame.timestamp_ns, frame.image,
                                          encoding=self.encodings.get(name, "raw"), jpeg_quality=self.jpeg_quality)
        self.pubs[name].put(wire, attachment=attachment_ns(self.wall_ns()))
        self.last_sent = frame.frame_id if self.last_sent is None else max(self.last_sent, frame.frame_id)
        self.status.count("processed")

    def _drain(self) -> None:
        """Lossless end: the frames still in flight would be lost with this session, so wait until the
        tracker has acknowledged them all."""
        if self.last_sent is None or self.stop.is_set():
            return
        done = self.gate.wait(self.last_sent + self.gate.window, timeout_s=self.credit_timeout_s, stop=self.stop)
        if not done and not self.stop.is_set():
            raise WorkerError(f"no credit from the tracker for the last frame {self.last_sent} within "
                              f"{self.credit_timeout_s:g} s")

    def close(self) -> None:
        """Release the credit gate and the status reporter (the sources belong to the caller)."""
        if self.gate is not None:
            self.gate.close()
        self.status.close()


def run_camera_worker(session: zenoh.Session, keys: Keys, sources: Mapping[str, Source], **options) -> dict:
    """``CameraWorker(session, keys, sources, **options).run()``: the counters when it ends."""
    return CameraWorker(session, keys, sources, **options).run()
