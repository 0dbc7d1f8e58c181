"""The three worker loops: camera -> frames, segment -> chamfer images, track -> poses.

Each ``run_*`` function takes an open zenoh session, the studio :class:`~service.bus.Keys`, its
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
from service.assembler import FrameSetAssembler
from service.bus import (CreditGate, Inbox, Keys, StatusReporter, attachment_ns, declare_publisher,
                         wait_until_alive, wait_until_matched)
from service.messages import ChamferMessage, FrameMessage, MessageError
from service.records import CreditMessage, PoseRecord

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
    (:class:`~service.bus.CreditGate`) and only once the tracker and a segment worker for each camera
    are alive (``startup_timeout_s``).  Raises :class:`WorkerError` when the consumers are not
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
                status.count("processed")
            status.tick(cameras=len(active))
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
                       idle_exit_s: float | None = None) -> dict:
    """One thread per camera: newest frame (live) or every frame in order (lossless) -> chamfer.

    A frame the segmenter rejects with MessageError is counted (``bad``); any other exception ends
    the worker with :class:`WorkerError` (the supervisor restarts the process).

    ``idle_exit_s``: return after that long without any frame once frames came and no camera worker is
    alive (replays: a lossless camera may wait long for credits while the tracker initialises); None = until stop.
    """
    lock = threading.Lock()
    last_frame: list = [None]  # idle time counts from the first frame
    crashed: dict[str, BaseException] = {}  # camera -> what ended its thread
    wires = {name: (Inbox(session, keys.frame(name), FrameMessage.from_bytes, mode=mode,
                          depth=1 if mode == "live" else 4096),
                    declare_publisher(session, keys.chamfer(name), mode=mode)) for name in segmenters}
    status = StatusReporter(session, keys, component)  # liveliness only once subscribed
    tokens = [session.liveliness().declare_token(keys.status(segment_token(name))) for name in segmenters]

    def loop(name: str, segment: Segmenter) -> None:
        inbox, pub = wires[name]
        try:
            while not stop.is_set():
                got = inbox.recv(0.05)
                if got is None:
                    continue
                last_frame[0] = time.monotonic()
                try:
                    out = segment(got.message, got.message.image())
                except MessageError as exc:
                    log.warning("camera %s frame %d: %s", name, got.message.frame_id, exc)
                    with lock:
                        status.count("bad")
                    continue
                if out is None:  # still learning the background
                    with lock:
                        status.count("learning")
                    continue
                att = attachment_ns(got.sent_ns) if got.sent_ns is not None else None
                pub.put(out.to_bytes(), attachment=att)
                with lock:
                    status.count("processed")
        except Exception as exc:  # a segmenter bug: the worker must fail loudly, not finish
            log.exception("camera %s: segmentation thread crashed", name)
            crashed[name] = exc
        finally:
            inbox.close()

    def gauges() -> dict:
        inboxes = [w[0] for w in wires.values()]
        return {"bad": sum(i.bad for i in inboxes), "dropped": sum(i.dropped for i in inboxes),
                "queue_depth": sum(len(i) for i in inboxes)}

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
        with lock:
            status.tick(state="finished", force=True, **gauges())
        status.close()
        for token in tokens:
            token.undeclare()
    if crashed:
        name, exc = next(iter(crashed.items()))
        raise WorkerError(f"camera {name}: segmentation failed: {exc.__class__.__name__}: {exc}") from exc
    return {**status.counters, **gauges()}


def run_track_worker(session: zenoh.Session, keys: Keys, cameras: tuple[str, ...], fit: Fitter, *,
                     mode: str = "live", set_timeout_s: float = 0.08, stop: threading.Event,
                     clock: Callable[[], float] = time.monotonic, wall_ns: Callable[[], int] = time.time_ns,
                     component: str = "track", max_frames: int | None = None, idle_exit_s: float | None = None,
                     on_pose: Callable[[PoseRecord], None] | None = None) -> dict:
    """Assemble chamfer sets, fit, publish one pose record per released set (``ok: false`` + reason
    when fitting fails — never silently dropped).  Lossless mode acknowledges each frame id.
    Returns after ``max_frames`` poses, ``idle_exit_s`` without input once input came, or ``stop``."""
    lossless = mode == "lossless"
    inbox = Inbox(session, keys.chamfer("*"), ChamferMessage.from_bytes, mode=mode,
                  depth=16 * len(cameras) if lossless else 2 * len(cameras))
    # lossless waits for every camera (a set released incomplete would not give the offline poses); only a
    # camera silent for LOSSLESS_SET_TIMEOUT_S is given up on, so a dead one stalls, not stops, the replay
    asm: FrameSetAssembler = FrameSetAssembler(cameras, mode=mode, timeout_s=set_timeout_s if not lossless
                                               else max(set_timeout_s, LOSSLESS_SET_TIMEOUT_S))
    pose_pub = declare_publisher(session, keys.pose, mode=mode)
    credit_pub = declare_publisher(session, keys.credit(TRACK_CONSUMER), mode="lossless") if lossless else None
    status = StatusReporter(session, keys, component, clock=clock)
    sent: dict[int, int] = {}
    done = 0

    def gauges() -> dict:
        return {"queue_depth": len(inbox), "stale_sets": asm.stale, "late": asm.late, "restarts": asm.restarts,
                "overflow": asm.overflow,
                "bad": inbox.bad,
                "dropped": inbox.dropped, "cameras": len(asm.present(clock()))}

    last_input = None  # idle time counts from the first input
    try:
        while not stop.is_set() and (max_frames is None or done < max_frames):
            if (idle_exit_s is not None and last_input is not None and clock() - last_input > idle_exit_s
                    and not len(asm)):
                break
            deadline = asm.next_deadline()
            wait = 0.05 if deadline is None else min(0.05, max(0.0, deadline - clock()))
            got = inbox.recv(wait)
            if got is not None:
                last_input = clock()
            while got is not None:
                msg: ChamferMessage = got.message
                cam = keys.camera_of(got.key)
                if cam != msg.camera:
                    status.count("mismatched_key")
                else:
                    asm.add(msg.camera, msg.frame_id, msg, clock())
                    if got.sent_ns is not None and asm.is_pending(msg.frame_id):
                        sent[msg.frame_id] = min(sent.get(msg.frame_id, got.sent_ns), got.sent_ns)
                got = inbox.recv(0) if len(inbox) else None
            for fs in asm.pop_ready(clock()):
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
                done += 1
            for fid in [f for f in sent if not asm.is_pending(f)]:  # bounded by the pending sets
                del sent[fid]
            status.tick(**gauges())
        return {**status.counters, "stale_sets": asm.stale, "late": asm.late, "bad": inbox.bad,
                "dropped": inbox.dropped}
    finally:
        status.tick(state="finished", force=True, **gauges())
        inbox.close()
        status.close()
