"""The three worker loops: camera -> frames, segment -> chamfer images, track -> poses.

Each ``run_*`` function takes an open zenoh session, the studio :class:`~service.wire.bus.Keys`, its
sources or processing callable, and a ``stop`` event; it returns a dict of counters when ``stop``
is set or its input ends.  Processes, argparse and signals live in ``service/commands/worker.py``.

Seams (adapted to the real components in ``service/components.py``):

- ``Segmenter``: ``(frame: FrameMessage, image_bgr (h, w, 3) uint8) -> ChamferMessage | None``
  (None: nothing to publish yet, e.g. still learning the background)
- ``Fitter``: ``(frame_id, timestamp_ns, chamfer: dict[camera, ChamferMessage]) -> dict`` (a DESIGN.md
  pose record, ``ok``/``reason`` included)

Latency: the camera worker attaches its wall-clock publish time (8 bytes) to each frame, the segment
worker forwards it, and the tracker reports ``latency_ms = now - earliest capture time of the set``
(across hosts this relies on NTP/PTP-synchronised clocks).
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Callable, Mapping

import zenoh

from capture.sources import EndOfStream, Source, SourceError, SourceTimeout
from service.flow.assembler import FrameSetAssembler
from service.wire.bus import (CreditGate, Inbox, Keys, StatusReporter, attachment_ns, declare_publisher, sent_ns_of,
                         wait_any, wait_until_alive, wait_until_matched)
from service.flow.demand import DemandPlanner, FrameRing
from service.wire.messages import ChamferMessage, FrameMessage, MessageError
from service.wire.records import HAVE_MAX_FRAMES, CreditMessage, DemandMessage, HaveMessage, PoseRecord

log = logging.getLogger("contourcap.worker")
Segmenter = Callable[[FrameMessage, object], ChamferMessage]
Fitter = Callable[[int, int, dict], dict]
TRACK_CONSUMER = "track"

#: lossless delivery: how long a frame set waits for a camera (CPU load, not loss, delays it)
LOSSLESS_SET_TIMEOUT_S = 60.0


class WorkerError(RuntimeError):
    """A worker could not go on (camera lost, peers unreachable, no credit): its process must exit
    non-zero so that the supervisor restarts it (a clean return means "finished", never restarted)."""


def segment_token(camera: str) -> str:
    """Liveliness name of "camera ``camera`` is being segmented" (lossless cameras wait for it)."""
    return f"segment.{camera}"


class EpochPacer:
    """Live replay pacing shared by all camera workers of a studio: a frame with session time ``t``
    is due at wall time ``epoch_ns + t``; frames already late by more than ``max_late_ns`` are
    skipped (so a restarted camera worker rejoins at the present, not at frame 0) — except that a
    late frame still goes out when none went out for ``max_gap_ns``: a host too slow to read the
    cameras at full rate then streams fewer, late frames instead of none at all."""

    def __init__(self, epoch_ns: int, *, max_late_ns: int = 20_000_000, max_gap_ns: int = 200_000_000,
                 wall_ns: Callable[[], int] = time.time_ns, sleep: Callable[[float], None] = time.sleep) -> None:
        self.epoch_ns, self.max_late_ns, self.max_gap_ns = int(epoch_ns), int(max_late_ns), int(max_gap_ns)
        self._wall_ns, self._sleep = wall_ns, sleep
        self._last_sent_ns: int | None = None

    def __call__(self, timestamp_ns: int) -> bool:
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


def run_camera_worker(session: zenoh.Session, keys: Keys, sources: Mapping[str, Source], *, mode: str = "live",
                      encodings: Mapping[str, str] | None = None, jpeg_quality: int = 90, window: int = 8,
                      stop: threading.Event, credit_timeout_s: float = 600.0, startup_timeout_s: float = 120.0,
                      wall_ns: Callable[[], int] = time.time_ns, component: str = "camera",
                      pace: Callable[[int], bool] | None = None) -> dict:
    """Read every source round-robin and publish its frames until all end or ``stop``.

    Lossless: frame ``k`` is published only once the tracker acknowledged ``k - window``
    (:class:`~service.wire.bus.CreditGate`) and only once the tracker and a segment worker for each camera
    are alive (``startup_timeout_s``); at the end it returns only once the tracker has acknowledged
    its last frame (closing the session earlier lost the frames still in flight).  Raises :class:`WorkerError` when the consumers are not
    reachable in time, a credit is missing for ``credit_timeout_s``, or a source fails (SourceError
    other than a timeout or the end of its stream); returns the counters when every source ended or
    ``stop`` was set.  Sources must already be open (context managers entered by the caller).  ``pace(timestamp_ns)``
    (e.g. :class:`EpochPacer`) may sleep and returns False to skip a frame (counted in ``skipped``).
    """
    encodings = dict(encodings or {})
    pubs = {name: declare_publisher(session, keys.frame(name), mode=mode) for name in sources}
    gate = CreditGate(session, keys, (TRACK_CONSUMER,), window=window) if mode == "lossless" else None
    status = StatusReporter(session, keys, component)
    active = dict(sources)
    last_sent: int | None = None
    try:
        if gate is not None:  # lossless: nothing may be published before the consumers listen
            needed = (TRACK_CONSUMER,) + tuple(segment_token(c) for c in sources)
            ready = (wait_until_alive(session, keys, needed, timeout_s=startup_timeout_s, stop=stop)
                     and wait_until_matched(pubs.values(), timeout_s=startup_timeout_s, stop=stop))
            if not ready:
                if stop.is_set():
                    return dict(status.counters)
                raise WorkerError(f"lossless: tracker or segment workers {list(needed)} not reachable "
                                  f"within {startup_timeout_s:g} s")
        while active and not stop.is_set():
            for name, src in list(active.items()):
                try:
                    frame = src.read()
                except SourceTimeout:
                    status.count("timeouts")
                    continue
                except EndOfStream:
                    del active[name]
                    continue
                except SourceError as exc:
                    status.count("errors")
                    status.tick(state="failed", force=True, cameras=len(active) - 1)
                    raise WorkerError(f"camera {name}: {exc}") from exc
                if pace is not None and not pace(frame.timestamp_ns):
                    status.count("skipped")
                    continue
                if gate is not None:
                    if not gate.wait(frame.frame_id, timeout_s=credit_timeout_s, stop=stop):
                        if stop.is_set():
                            return dict(status.counters)
                        raise WorkerError(f"camera {name}: no credit from the tracker for frame "
                                          f"{frame.frame_id} within {credit_timeout_s:g} s")
                msg = FrameMessage.from_image(name, frame.frame_id, frame.timestamp_ns, frame.image,
                                              encoding=encodings.get(name, "raw"), jpeg_quality=jpeg_quality)
                pubs[name].put(msg.to_bytes(), attachment=attachment_ns(wall_ns()))
                last_sent = frame.frame_id if last_sent is None else max(last_sent, frame.frame_id)
                status.count("processed")
            status.tick(cameras=len(active))
        if gate is not None and last_sent is not None and not stop.is_set():
            # the frames still in flight would be lost with this session: wait until the tracker has them all
            if not gate.wait(last_sent + gate.window, timeout_s=credit_timeout_s, stop=stop) and not stop.is_set():
                raise WorkerError(f"no credit from the tracker for the last frame {last_sent} within "
                                  f"{credit_timeout_s:g} s")
        status.tick(state="finished", force=True)
        return dict(status.counters)
    finally:
        if gate is not None:
            gate.close()
        status.close()


def _cameras_alive(session: zenoh.Session, keys: Keys) -> bool:
    """Whether any camera worker's liveliness token is visible."""
    prefix = keys.status("camera")
    replies = session.liveliness().get(keys.status("*"), timeout=1.0)
    return any(r.ok is not None and str(r.ok.key_expr).startswith(prefix) for r in replies)


def run_segment_worker(session: zenoh.Session, keys: Keys, segmenters: Mapping[str, Segmenter], *,
                       mode: str = "live", stop: threading.Event, component: str = "segment",
                       idle_exit_s: float | None = None, ring_size: int = 8, demand_wait_s: float = 0.5) -> dict:
    """One thread per camera.  Lossless: every frame in order -> chamfer.  Live: the newest
    ``ring_size`` frames of each camera are kept undecoded (:class:`~service.flow.demand.FrameRing`), their
    ids announced on ``cam/<cam>/have``, and only the frames the tracker demands on ``demand/track``
    are decoded and segmented (:mod:`service.flow.demand`); a demanded frame not held is skipped (or
    waited for up to ``demand_wait_s`` if it has not arrived yet) and counted in ``missed``.  A
    segmenter still learning its background (it returned None) is given every new frame until it
    has learnt.

    A frame the segmenter rejects with MessageError is counted (``bad``); any other exception ends
    the worker with :class:`WorkerError` (the supervisor restarts the process).

    ``idle_exit_s``: return after that long without any frame once frames came and no camera worker is
    alive (replays: a lossless camera may wait long for credits while the tracker initialises); None = until stop.
    """
    lock = threading.Lock()
    last_frame: list = [None]  # idle time counts from the first frame
    crashed: dict[str, BaseException] = {}  # camera -> what ended its thread
    live = mode == "live"
    # chamfers and demands are few (demanded frames only) and each costs a segmentation: never dropped
    pubs = {name: declare_publisher(session, keys.chamfer(name), mode="lossless") for name in segmenters}
    inboxes = {} if live else {name: Inbox(session, keys.frame(name), FrameMessage.from_bytes, mode=mode, depth=4096)
                               for name in segmenters}
    rings = {name: FrameRing(name, size=min(ring_size, HAVE_MAX_FRAMES)) for name in segmenters} if live else {}
    have_pubs = {name: declare_publisher(session, keys.have(name)) for name in rings}
    subs = []
    status = StatusReporter(session, keys, component)

    def count(name: str, n: float = 1) -> None:
        with lock:
            status.count(name, n)

    def on_frame(ring: FrameRing):
        def callback(sample: zenoh.Sample) -> None:
            last_frame[0] = time.monotonic()
            try:
                ring.put(sample.payload.to_bytes(), sent_ns_of(sample))
            except MessageError as exc:
                count("bad")
                log.debug("camera %s: bad frame: %s", ring.camera, exc)
        return callback

    def on_demand(sample: zenoh.Sample) -> None:
        try:
            demand = DemandMessage.from_bytes(sample.payload.to_bytes())
        except MessageError:
            count("bad")
            return
        if demand.consumer == TRACK_CONSUMER:
            now = time.monotonic()
            for ring in rings.values():
                ring.demand(demand.frame_id, now)

    if live:  # subscribed before the liveliness tokens below announce this worker
        subs = [session.declare_subscriber(keys.frame(name), on_frame(ring)) for name, ring in rings.items()]
        subs.append(session.declare_subscriber(keys.demand(TRACK_CONSUMER), on_demand))
    tokens = [session.liveliness().declare_token(keys.status(segment_token(name))) for name in segmenters]

    def segment_one(name: str, segment: Segmenter, msg: FrameMessage | bytes) -> ChamferMessage | None | bool:
        """The segmenter's output for one frame; False if the frame was bad (counted)."""
        try:
            if not isinstance(msg, FrameMessage):
                msg = FrameMessage.from_bytes(msg)
            return segment(msg, msg.image())
        except MessageError as exc:
            log.warning("camera %s: %s", name, exc)
            count("bad")
            return False

    def publish(name: str, out: ChamferMessage, sent_ns: int | None) -> None:
        pubs[name].put(out.to_bytes(), attachment=attachment_ns(sent_ns) if sent_ns is not None else None)
        count("processed")

    def lossless_loop(name: str, segment: Segmenter) -> None:
        inbox = inboxes[name]
        while not stop.is_set():
            got = inbox.recv(0.05)
            if got is None:
                continue
            last_frame[0] = time.monotonic()
            out = segment_one(name, segment, got.message)
            if out is None:  # still learning the background
                count("learning")
            elif out is not False:
                publish(name, out, got.sent_ns)

    def live_loop(name: str, segment: Segmenter) -> None:
        ring, learning = rings[name], False
        while not stop.is_set():
            with ring.cv:
                ring.cv.wait_for(ring.busy, 0.05)
            held = ring.take_news()
            if held is not None:
                have_pubs[name].put(HaveMessage(name, held).to_bytes())
                newest = ring.newest() if learning else None
                if newest is not None:  # learning from every frame (not published: not demanded)
                    learning = segment_one(name, segment, newest[1]) is None
            missed, got = ring.next_demanded(time.monotonic(), wait_s=demand_wait_s)
            if missed:
                count("missed", len(missed))
            if got is None:
                continue
            fid, data, sent_ns = got
            out = segment_one(name, segment, data)
            if out is None:
                learning = True
                count("learning")
            elif out is not False:
                publish(name, out, sent_ns)

    def loop(name: str, segment: Segmenter) -> None:
        try:
            (live_loop if live else lossless_loop)(name, segment)
        except Exception as exc:  # a segmenter bug: the worker must fail loudly, not finish
            log.exception("camera %s: segmentation thread crashed", name)
            crashed[name] = exc

    def gauges() -> dict:
        if live:
            return {"evicted": sum(r.evicted for r in rings.values()),
                    "queue_depth": sum(len(r) for r in rings.values())}
        return {"bad": sum(i.bad for i in inboxes.values()), "dropped": sum(i.dropped for i in inboxes.values()),
                "queue_depth": sum(len(i) for i in inboxes.values())}

    threads = [threading.Thread(target=loop, args=item, name=f"segment-{item[0]}", daemon=True)
               for item in segmenters.items()]
    for t in threads:
        t.start()
    try:
        while not stop.is_set() and all(t.is_alive() for t in threads):
            if (idle_exit_s is not None and last_frame[0] is not None and time.monotonic() - last_frame[0] > idle_exit_s
                    and not _cameras_alive(session, keys)):  # a camera waiting for credits is not finished
                break
            with lock:
                status.tick(**gauges())
            stop.wait(0.1)
    finally:
        stop.set()
        for t in threads:
            t.join(2.0)
        for sub in subs + list(inboxes.values()):
            try:
                (sub.close if isinstance(sub, Inbox) else sub.undeclare)()
            except Exception:  # session already closed
                pass
        with lock:
            status.tick(state="finished", force=True, **gauges())
        status.close()
        for token in tokens:
            token.undeclare()
    if crashed:
        name, exc = next(iter(crashed.items()))
        raise WorkerError(f"camera {name}: segmentation failed: {exc.__class__.__name__}: {exc}") from exc
    with lock:
        return {**status.counters, **gauges()}


def run_track_worker(session: zenoh.Session, keys: Keys, cameras: tuple[str, ...], fit: Fitter, *,
                     mode: str = "live", set_timeout_s: float = 0.08, stop: threading.Event,
                     clock: Callable[[], float] = time.monotonic, wall_ns: Callable[[], int] = time.time_ns,
                     component: str = "track", max_frames: int | None = None, idle_exit_s: float | None = None,
                     on_pose: Callable[[PoseRecord], None] | None = None, absent_after_s: float = 0.5,
                     demand_timeout_s: float | None = None) -> dict:
    """Assemble chamfer sets, fit, publish one pose record per released set (``ok: false`` + reason
    when fitting fails — never silently dropped).  Lossless mode acknowledges each frame id.
    Live mode demands the frames it fits (:class:`~service.flow.demand.DemandPlanner`: the newest frame
    id the live cameras' segment workers hold, by their have notices; a camera silent for
    ``absent_after_s`` is left out) and, once a demanded set is complete, demands the next one
    before fitting it.  ``demand_timeout_s`` (default ``max(0.25, 2 * set_timeout_s)``): a demand
    that brought nothing is given up.
    Returns after ``max_frames`` poses, ``idle_exit_s`` without input once input came, or ``stop``."""
    lossless = mode == "lossless"
    cv = threading.Condition()
    inbox = Inbox(session, keys.chamfer("*"), ChamferMessage.from_bytes, mode=mode,
                  depth=16 * len(cameras) if lossless else 2 * len(cameras), cv=cv)
    haves = None if lossless else Inbox(session, keys.have("*"), HaveMessage.from_bytes, depth=64 * len(cameras),
                                        cv=cv)
    planner = None if lossless else DemandPlanner(
        cameras, absent_after_s=absent_after_s, startup_grace_s=absent_after_s,
        demand_timeout_s=max(0.25, 2 * set_timeout_s) if demand_timeout_s is None else demand_timeout_s)
    # lossless waits for every camera (a set released incomplete would not give the offline poses); only a
    # camera silent for LOSSLESS_SET_TIMEOUT_S is given up on, so a dead one stalls, not stops, the replay
    asm: FrameSetAssembler = FrameSetAssembler(cameras, mode=mode, absent_after_s=absent_after_s if not lossless
                                               else 1.0, timeout_s=set_timeout_s if not lossless
                                               else max(set_timeout_s, LOSSLESS_SET_TIMEOUT_S))
    pose_pub = declare_publisher(session, keys.pose, mode=mode)
    credit_pub = declare_publisher(session, keys.credit(TRACK_CONSUMER), mode="lossless") if lossless else None
    demand_pub = None if lossless else declare_publisher(session, keys.demand(TRACK_CONSUMER), mode="lossless")
    status = StatusReporter(session, keys, component, clock=clock)
    sent: dict[int, int] = {}
    done = 0

    def gauges() -> dict:
        out = {"queue_depth": len(inbox), "stale_sets": asm.stale, "late": asm.late, "restarts": asm.restarts,
               "overflow": asm.overflow, "bad": inbox.bad, "dropped": inbox.dropped,
               "cameras": len(asm.present(clock()))}
        if planner is not None:
            out.update(bad=inbox.bad + haves.bad, demands=planner.demands, demand_timeouts=planner.timeouts,
                       cameras=len(planner.live(clock())))
        return out

    def demand() -> None:
        fid = planner.next_demand(clock(), hold=asm.is_pending) if planner is not None else None
        if fid is not None:
            demand_pub.put(DemandMessage(TRACK_CONSUMER, fid).to_bytes())

    def take_haves() -> None:
        for got in haves.drain():
            msg: HaveMessage = got.message
            if keys.camera_of(got.key) != msg.camera:
                status.count("mismatched_key")
            elif planner.have(msg.camera, msg.frame_ids, clock()):
                asm.seen(msg.camera, clock())

    def take_chamfers() -> None:
        for got in inbox.drain():
            msg: ChamferMessage = got.message
            if keys.camera_of(got.key) != msg.camera:
                status.count("mismatched_key")
                continue
            if planner is not None and not planner.wanted(msg.frame_id):
                status.count("undemanded")
                continue
            asm.add(msg.camera, msg.frame_id, msg, clock())
            if got.sent_ns is not None and asm.is_pending(msg.frame_id):
                sent[msg.frame_id] = min(sent.get(msg.frame_id, got.sent_ns), got.sent_ns)

    def finish(fs) -> None:
        """Fit one released set and publish its pose (and its credit, lossless)."""
        first = next(iter(fs.items.values()))
        try:
            record = dict(fit(fs.frame_id, first.timestamp_ns, fs.items))
        except Exception as exc:  # the fitter is a plug-in; a crash costs one frame, not the service
            log.exception("frame %d: fitting failed", fs.frame_id)
            record = {"frame": fs.frame_id, "timestamp_ns": first.timestamp_ns, "ok": False,
                      "reason": f"fitting failed: {exc.__class__.__name__}: {exc}"[:200]}
        record.setdefault("cameras", len(fs.items))
        t0 = sent.pop(fs.frame_id, None)
        if t0 is not None:
            record["latency_ms"] = (wall_ns() - t0) / 1e6
            status.latency(record["latency_ms"])
        try:
            pose = PoseRecord.from_dict(record)
        except MessageError as exc:
            pose = PoseRecord.from_dict({"frame": fs.frame_id, "timestamp_ns": first.timestamp_ns,
                                         "ok": False, "reason": f"invalid pose record: {exc}"[:200],
                                         "cameras": len(fs.items)})
        pose_pub.put(pose.to_bytes())
        if on_pose is not None:
            on_pose(pose)
        if credit_pub is not None:
            credit_pub.put(CreditMessage(TRACK_CONSUMER, fs.frame_id).to_bytes())
        status.count("processed")
        status.count("missing_cameras", len(fs.missing))

    last_input = None  # idle time counts from the first input
    try:
        while not stop.is_set() and (max_frames is None or done < max_frames):
            if (idle_exit_s is not None and last_input is not None and clock() - last_input > idle_exit_s
                    and not len(asm) and not len(inbox) and not (haves is not None and len(haves))):
                break
            demand()
            deadline = asm.next_deadline()
            wait = 0.05 if deadline is None else min(0.05, max(0.0, deadline - clock()))
            if wait_any([inbox] if haves is None else [inbox, haves], wait):
                last_input = clock()
            if haves is not None:
                take_haves()
            take_chamfers()
            for fs in asm.pop_ready(clock()):
                if planner is not None:  # pipelining: the next set is segmented while this one is fitted
                    planner.released(fs.frame_id)
                    demand()
                finish(fs)
                done += 1
                last_input = clock()  # a long fit (re-initialisation) is not idleness
            for fid in [f for f in sent if not asm.is_pending(f)]:  # bounded by the pending sets
                del sent[fid]
            status.tick(**gauges())
        return {**status.counters, **gauges()}
    finally:
        status.tick(state="finished", force=True, **gauges())
        inbox.close()
        if haves is not None:
            haves.close()
        status.close()
