"""The segment worker: frames in, chamfer images out, one thread per camera."""

from __future__ import annotations

import logging
import threading
import time
from typing import Mapping

import zenoh

from service.flow.demand import FrameRing
from service.wire.bus import Inbox, Keys, StatusReporter, attachment_ns, declare_publisher, sent_ns_of
from service.wire.messages import ChamferMessage, FrameMessage, MessageError
from service.wire.records import HAVE_MAX_FRAMES, DemandMessage, HaveMessage
from service.workers.base import TRACK_CONSUMER, Segmenter, WorkerError, segment_token

__all__ = ["SegmentWorker", "run_segment_worker"]

log = logging.getLogger("contourcap.worker")


def _cameras_alive(session: zenoh.Session, keys: Keys) -> bool:
    """Whether any camera worker's liveliness token is visible."""
    prefix = keys.status("camera")
    replies = session.liveliness().get(keys.status("*"), timeout=1.0)
    return any(r.ok is not None and str(r.ok.key_expr).startswith(prefix) for r in replies)


class SegmentWorker:
    """Segment every camera's frames in a thread per camera.

    Lossless: every frame in order -> chamfer.  Live: the newest ``ring_size`` frames of each camera
    are kept undecoded (:class:`~service.flow.demand.FrameRing`), their ids announced on
    ``cam/<cam>/have``, and only the frames the tracker demands on ``demand/track`` are decoded and
    segmented (:mod:`service.flow.demand`); a demanded frame not held is skipped (or waited for up to
    ``demand_wait_s`` if it has not arrived yet) and counted in ``missed``; a demand naming a
    camera's region of interest has that frame segmented only there (segmenters with ``takes_roi``).  A segmenter still
    learning its background (it returned None) is given every new frame until it has learnt.

    A frame the segmenter rejects with MessageError is counted (``bad``); any other exception ends
    the worker with :class:`WorkerError` (the supervisor restarts the process).

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    segmenters : mapping
        Camera name -> ``Segmenter``.
    mode : {"live", "lossless"}
    stop : threading.Event
    component : str
        Status name.
    idle_exit_s : float, optional
        Return after that long without any frame once frames came and no camera worker is alive
        (replays: a lossless camera may wait long for credits while the tracker initialises);
        None: until ``stop``.
    ring_size, demand_wait_s : int, float
        Live: frames held per camera; how long a demanded frame not yet arrived is waited for (s).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, segmenters: Mapping[str, Segmenter], *,
                 mode: str = "live", stop: threading.Event, component: str = "segment",
                 idle_exit_s: float | None = None, ring_size: int = 8, demand_wait_s: float = 0.5) -> None:
        self.session, self.keys, self.segmenters, self.stop = session, keys, dict(segmenters), stop
        self.live, self.idle_exit_s, self.demand_wait_s = mode == "live", idle_exit_s, demand_wait_s
        self.lock = threading.Lock()
        self.last_frame: float | None = None  # idle time counts from the first frame
        self.crashed: dict[str, BaseException] = {}  # camera -> what ended its thread
        names = list(self.segmenters)
        # chamfers and demands are few (demanded frames only) and each costs a segmentation: never dropped
        self.pubs = {name: declare_publisher(session, keys.chamfer(name), mode="lossless") for name in names}
        self.inboxes = {} if self.live else {
            name: Inbox(session, keys.frame(name), FrameMessage.from_bytes, mode=mode, depth=4096) for name in names}
        self.rings = ({name: FrameRing(name, size=min(ring_size, HAVE_MAX_FRAMES)) for name in names}
                      if self.live else {})
        self.have_pubs = {name: declare_publisher(session, keys.have(name)) for name in self.rings}
        self.demand_rois: dict[int, dict] = {}  # frame id -> camera -> region of interest (live demands)
        self.subs = []
        self.status = StatusReporter(session, keys, component)
        if self.live:  # subscribed before the liveliness tokens below announce this worker
            self.subs = [session.declare_subscriber(keys.frame(name), self._on_frame(ring))
                         for name, ring in self.rings.items()]
            self.subs.append(session.declare_subscriber(keys.demand(TRACK_CONSUMER), self._on_demand))
        self.tokens = [session.liveliness().declare_token(keys.status(segment_token(name))) for name in names]

    def count(self, name: str, n: float = 1) -> None:
        """Add ``n`` to counter ``name`` (thread-safe)."""
        with self.lock:
            self.status.count(name, n)

    def gauges(self) -> dict:
        """Queue gauges for the status messages and the returned counters."""
        if self.live:
            return {"evicted": sum(r.evicted for r in self.rings.values()),
                    "rejected": sum(r.rejected for r in self.rings.values()),
                    "queue_depth": sum(len(r) for r in self.rings.values())}
        return {"bad": sum(i.bad for i in self.inboxes.values()),
                "dropped": sum(i.dropped for i in self.inboxes.values()),
                "queue_depth": sum(len(i) for i in self.inboxes.values())}

    def _on_frame(self, ring: FrameRing):
        def callback(sample: zenoh.Sample) -> None:
            self.last_frame = time.monotonic()
            try:
                ring.put(sample.payload.to_bytes(), sent_ns_of(sample))
            except MessageError as exc:
                self.count("bad")
                log.debug("camera %s: bad frame: %s", ring.camera, exc)
        return callback

    def _on_demand(self, sample: zenoh.Sample) -> None:
        try:
            demand = DemandMessage.from_bytes(sample.payload.to_bytes())
        except MessageError:
            self.count("bad")
            return
        if demand.consumer == TRACK_CONSUMER:
            now = time.monotonic()
            # the demanded frame's regions of interest, the newest few kept (not for a demand no camera
            # takes: a far-future flood would push the real demands' regions out)
            if any(ring.demandable(demand.frame_id) for ring in self.rings.values()):
                with self.lock:
                    self.demand_rois[demand.frame_id] = demand.rois or {}
                    while len(self.demand_rois) > 16:
                        del self.demand_rois[next(iter(self.demand_rois))]
            for ring in self.rings.values():
                ring.demand(demand.frame_id, now)

    def _segment_one(self, name: str, segment: Segmenter, msg: FrameMessage | bytes,
                     roi: tuple[int, int, int, int] | None = None) -> ChamferMessage | None | bool:
        """The segmenter's output for one frame (within ``roi`` if given and the segmenter takes one:
        ``takes_roi``); False if the frame was bad (counted)."""
        try:
            if not isinstance(msg, FrameMessage):
                msg = FrameMessage.from_bytes(msg)
            if roi is not None and getattr(segment, "takes_roi", False):
                return segment(msg, msg.image(), roi=roi)
            return segment(msg, msg.image())
        except MessageError as exc:
            log.warning("camera %s: %s", name, exc)
            self.count("bad")
            return False

    def _count_kind(self, segment: Segmenter, roi: tuple[int, int, int, int] | None, cpu_s: float) -> None:
        """Count a demanded live frame as ``roi`` or ``whole`` (counters), add its thread CPU seconds
        ``cpu_s`` to ``roi_cpu_s`` or ``whole_cpu_s`` and an ROI's area to ``roi_px`` (pixels)."""
        if roi is not None and getattr(segment, "takes_roi", False):
            self.count("roi")
            self.count("roi_cpu_s", cpu_s)
            self.count("roi_px", (roi[2] - roi[0]) * (roi[3] - roi[1]))
        else:
            self.count("whole")
            self.count("whole_cpu_s", cpu_s)

    def _publish(self, name: str, out: ChamferMessage, sent_ns: int | None) -> None:
        self.pubs[name].put(out.to_bytes(), attachment=attachment_ns(sent_ns) if sent_ns is not None else None)
        self.count("processed")

    def lossless_loop(self, name: str, segment: Segmenter) -> None:
        """Every frame of camera ``name`` in order until ``stop``."""
        inbox = self.inboxes[name]
        while not self.stop.is_set():
            got = inbox.recv(0.05)
            if got is None:
                continue
            self.last_frame = time.monotonic()
            out = self._segment_one(name, segment, got.message)
            if out is None:  # still learning the background
                self.count("learning")
            elif out is not False:
                self._publish(name, out, got.sent_ns)

    def live_loop(self, name: str, segment: Segmenter) -> None:
        """Announce the frames held of camera ``name``, segment the demanded ones, until ``stop``."""
        ring, learning = self.rings[name], False
        while not self.stop.is_set():
            with ring.cv:
                ring.cv.wait_for(ring.busy, 0.05)
            held = ring.take_news()
            if held is not None:
                self.have_pubs[name].put(HaveMessage(name, held).to_bytes())
                newest = ring.newest() if learning else None
                if newest is not None:  # learning from every frame (not published: not demanded)
                    learning = self._segment_one(name, segment, newest[1]) is None
            missed, got = ring.next_demanded(time.monotonic(), wait_s=self.demand_wait_s)
            if missed:
                self.count("missed", len(missed))
            if got is None:
                continue
            fid, data, sent_ns = got
            with self.lock:
                roi = self.demand_rois.get(fid, {}).get(name)
            t0 = time.thread_time()
            out = self._segment_one(name, segment, data, roi)
            self._count_kind(segment, roi, time.thread_time() - t0)
            if out is None:
                learning = True
                self.count("learning")
            elif out is not False:
                self._publish(name, out, sent_ns)

    def _thread(self, name: str, segment: Segmenter) -> None:
        try:
            (self.live_loop if self.live else self.lossless_loop)(name, segment)
        except Exception as exc:  # a segmenter bug: the worker must fail loudly, not finish
            log.exception("camera %s: segmentation thread crashed", name)
            self.crashed[name] = exc

    def _idle(self) -> bool:
        """Frames came, none for ``idle_exit_s``, and no camera worker is alive (one waiting for
        credits is not finished)."""
        return (self.idle_exit_s is not None and self.last_frame is not None
                and time.monotonic() - self.last_frame > self.idle_exit_s
                and not _cameras_alive(self.session, self.keys))

    def run(self) -> dict:
        """Segment until ``stop``, a thread crashed or idle; returns the counters and gauges.

        Raises :class:`WorkerError` naming the camera whose segmentation crashed.
        """
        for segment in self.segmenters.values():  # compile kernels before the first frame, not on it
            if hasattr(segment, "warm_up"):
                segment.warm_up()
        threads = [threading.Thread(target=self._thread, args=item, name=f"segment-{item[0]}", daemon=True)
                   for item in self.segmenters.items()]
        for t in threads:
            t.start()
        try:
            while not self.stop.is_set() and all(t.is_alive() for t in threads):
                if self._idle():
                    break
                with self.lock:
                    self.status.tick(**self.gauges())
                self.stop.wait(0.1)
        finally:
            self.stop.set()
            for t in threads:
                t.join(2.0)
            self.close()
        if self.crashed:
            name, exc = next(iter(self.crashed.items()))
            raise WorkerError(f"camera {name}: segmentation failed: {exc.__class__.__name__}: {exc}") from exc
        with self.lock:
            return {**self.status.counters, **self.gauges()}

    def close(self) -> None:
        """Undeclare the subscriptions, report 'finished', withdraw the liveliness tokens."""
        for sub in self.subs + list(self.inboxes.values()):
            try:
                (sub.close if isinstance(sub, Inbox) else sub.undeclare)()
            except Exception:  # session already closed
                pass
        with self.lock:
            self.status.tick(state="finished", force=True, **self.gauges())
        self.status.close()
        for token in self.tokens:
            token.undeclare()


def run_segment_worker(session: zenoh.Session, keys: Keys, segmenters: Mapping[str, Segmenter], **options) -> dict:
    """``SegmentWorker(session, keys, segmenters, **options).run()``: the counters when it ends."""
    return SegmentWorker(session, keys, segmenters, **options).run()
