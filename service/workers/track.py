"""The track worker: chamfer images in, frame sets assembled and fitted, pose records out.

A set whose fit fails still gets a record (``ok: false`` and a reason): never silently dropped.
Lossless mode acknowledges each frame id (credits) and waits for every camera (a set released
incomplete would not give the offline poses); only a camera silent for
:data:`LOSSLESS_SET_TIMEOUT_S` is given up on, so a dead one stalls, not stops, the replay.
Live mode demands the frames it fits (:class:`~service.flow.demand.DemandPlanner`: the newest
frame id the live cameras' segment workers hold, by their have notices; a camera silent for
``absent_after_s`` is left out) and, once a demanded set is complete, demands the next one
before fitting it, naming where the body can be in each camera when the fitter predicts it
(``rois``); a fitter with ``demand_interval_s`` (seconds) is demanded sets at most that often
(while it initialises, say).  Each record gets ``fit_ms`` (the fit, wall clock), ``fit_cpu_ms``
(the CPU time of this worker's thread during the fit: below ``fit_ms`` by the time the fit waited
for a core other processes held) and ``latency_ms`` (capture to publish: the camera worker's
publish time, forwarded by the segment worker, to this worker's publish).  A
fitter with ``warm_up()`` is warmed up before the first frame.

The thread that fits runs ``priority_boost`` nice levels above the process (Linux niceness is per
thread; threads it starts inherit it): the camera and segment workers feeding it share the cores,
and without it the fit waits for a core while they run ahead.  Raising priority needs
``CAP_SYS_NICE`` or an ``RLIMIT_NICE`` allowance; when refused the worker logs it, counts
``priority_refused`` and runs as it is.

A fitter with an ``auto_subject`` (``service.workers.auto_subject``) that has adopted a calibrated
subject gets it published on ``contourcap/<studio>/subject`` after the next pose, and again every
:data:`SUBJECT_REPUBLISH_S` (late subscribers), counted as ``subject_published``.
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from typing import Callable

import zenoh

from capture.sync import FrameSetAssembler
from service.flow.demand import DemandPlanner
from service.wire.bus import Inbox, Keys, StatusReporter, declare_publisher, wait_any
from service.wire.messages import ChamferMessage, FrameMessage, MessageError
from service.wire.records import CreditMessage, DemandMessage, HaveMessage, PoseRecord
from service.workers.base import TRACK_CONSUMER, Fitter, renice_thread

__all__ = ["LOSSLESS_SET_TIMEOUT_S", "TrackWorker", "run_track_worker"]

log = logging.getLogger("contourcap.worker")

LOSSLESS_SET_TIMEOUT_S = 60.0
SUBJECT_REPUBLISH_S = 10.0
"""Seconds between two publications of an adopted subject."""
DEFAULT_PRIORITY_BOOST = 5
"""Nice levels the fitting thread is raised by (see the module docstring)."""
# the largest chamfer message taken (a 1920x1200 camera's two uint16 images are ~9 MB): with the inbox
# depths below, a live track worker holds at most 2 x cameras x 16 MiB of received chamfers
CHAMFER_MAX_BYTES = 16 * 1024 * 1024
"""Lossless delivery: how long a frame set waits for a camera (CPU load, not loss, delays it), in seconds."""


class TrackWorker:
    """Assemble chamfer sets, fit them, publish one pose record per released set (see the module docstring).

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    cameras : tuple of str
        The studio's cameras.
    fit : Fitter
    mode : {"live", "lossless"}
    set_timeout_s : float
        Live: how long a set waits for missing cameras.
    stop : threading.Event
    clock, wall_ns : callable
        Monotonic clock (s) for the assembly, wall clock (ns) for the latency.
    component : str
        Status name.
    max_frames, idle_exit_s : int, float, optional
        Return after this many poses / this long without input once input came.
    on_pose : callable (PoseRecord) -> None, optional
        Called with every published record.
    absent_after_s : float
        Live: silence after which a camera is left out of the sets.
    demand_timeout_s : float, optional
        Live: a demand that brought nothing is given up after this (default ``max(0.25, 2 * set_timeout_s)``).
    inputs : {"chamfer", "frames"}
        What the fitter takes: the segment workers' chamfer images, or the camera frames themselves
        (``service.workers.blob_track``; live sets are then the newest frame per camera, no demand).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, cameras: tuple[str, ...], fit: Fitter, *,
                 mode: str = "live", set_timeout_s: float = 0.08, stop: threading.Event,
                 clock: Callable[[], float] = time.monotonic, wall_ns: Callable[[], int] = time.time_ns,
                 component: str = "track", max_frames: int | None = None, idle_exit_s: float | None = None,
                 on_pose: Callable[[PoseRecord], None] | None = None, absent_after_s: float = 0.5,
                 demand_timeout_s: float | None = None, inputs: str = "chamfer",
                 priority_boost: int = DEFAULT_PRIORITY_BOOST) -> None:
        self.priority_boost = int(priority_boost)
        self.keys, self.fit, self.stop, self.clock, self.wall_ns = keys, fit, stop, clock, wall_ns
        self.max_frames, self.idle_exit_s, self.on_pose = max_frames, idle_exit_s, on_pose
        lossless = mode == "lossless"
        cv = threading.Condition()
        frames = inputs == "frames"  # the fitter reads the camera frames itself: no segment worker, no demand
        self.inbox = Inbox(session, keys.frame("*") if frames else keys.chamfer("*"),
                           FrameMessage.from_bytes if frames else functools.partial(ChamferMessage.from_bytes,
                                                                                    max_bytes=CHAMFER_MAX_BYTES),
                           mode=mode, depth=16 * len(cameras) if lossless else 2 * len(cameras), cv=cv)
        self.planner = None if lossless or frames else DemandPlanner(
            cameras, absent_after_s=absent_after_s, startup_grace_s=absent_after_s,
            demand_timeout_s=max(0.25, 2 * set_timeout_s) if demand_timeout_s is None else demand_timeout_s)
        # a notice that cannot be taken (another camera's key, no plausible id) is dropped on receipt:
        # a flood of them then never displaces a camera's real notice nor wakes this loop
        self.haves = None if self.planner is None else Inbox(
            session, keys.have("*"), HaveMessage.from_bytes, depth=64 * len(cameras), cv=cv, latest_per_key=True,
            keep=lambda key, msg: (keys.camera_of(key) == msg.camera
                                   and self.planner.plausible(msg.camera, msg.frame_ids, self.clock())))
        # lossless: every camera is waited for (absent_after_s None); "cameras" reports those heard within 1 s
        self.absent_after_s = 1.0 if lossless else absent_after_s
        self.asm: FrameSetAssembler = FrameSetAssembler(
            cameras, mode=mode, absent_after_s=None if lossless else absent_after_s,
            timeout_s=max(set_timeout_s, LOSSLESS_SET_TIMEOUT_S) if lossless else set_timeout_s)
        self.pose_pub = declare_publisher(session, keys.pose, mode=mode)
        self.credit_pub = (declare_publisher(session, keys.credit(TRACK_CONSUMER), mode="lossless") if lossless
                           else None)
        self.demand_pub = None if lossless else declare_publisher(session, keys.demand(TRACK_CONSUMER),
                                                                  mode="lossless")
        self.status = StatusReporter(session, keys, component, clock=clock)
        self.subject_pub = (declare_publisher(session, keys.subject, mode="lossless")
                            if getattr(fit, "auto_subject", None) is not None else None)
        self._subject_sent: float | None = None
        self.sent: dict[int, int] = {}  # frame id -> earliest capture wall time (ns) of its pending set
        self._demanded_at: float | None = None

    def gauges(self) -> dict:
        """Assembly and queue gauges for the status messages and the returned counters."""
        asm, inbox = self.asm, self.inbox
        out = {"queue_depth": len(inbox), "stale_sets": asm.stale, "late": asm.late, "restarts": asm.restarts,
               "overflow": asm.overflow, "bad": inbox.bad, "dropped": inbox.dropped,
               "cameras": len(asm.present(self.clock(), self.absent_after_s))}
        if self.planner is not None:
            out.update(bad=inbox.bad + self.haves.bad, rejected=self.planner.rejected + self.haves.refused,
                       have_dropped=self.haves.dropped, demands=self.planner.demands,
                       demand_timeouts=self.planner.timeouts, cameras=len(self.planner.live(self.clock())))
        return out

    def _demand(self) -> None:
        if self.planner is None:
            return
        interval = float(getattr(self.fit, "demand_interval_s", 0.0))
        if interval > 0 and self._demanded_at is not None and self.clock() - self._demanded_at < interval:
            return
        fid = self.planner.next_demand(self.clock(), hold=self.asm.is_pending)
        if fid is not None:  # a fitter that predicts where the body is names each camera's region of interest
            self._demanded_at = self.clock()
            rois = self.fit.rois(fid) if hasattr(self.fit, "rois") else None
            self.demand_pub.put(DemandMessage(TRACK_CONSUMER, fid, rois).to_bytes())

    def _take_haves(self) -> None:
        for got in self.haves.drain():
            msg: HaveMessage = got.message
            if self.keys.camera_of(got.key) != msg.camera:
                self.status.count("mismatched_key")
            elif self.planner.have(msg.camera, msg.frame_ids, self.clock()):
                self.asm.seen(msg.camera, self.clock())

    def _take_chamfers(self) -> None:
        for got in self.inbox.drain():
            msg: ChamferMessage = got.message
            if self.keys.camera_of(got.key) != msg.camera:
                self.status.count("mismatched_key")
                continue
            if self.planner is not None and not self.planner.wanted(msg.frame_id):
                self.status.count("undemanded")
                continue
            self.asm.add(msg.camera, msg.frame_id, msg, self.clock())
            if got.sent_ns is not None and self.asm.is_pending(msg.frame_id):
                self.sent[msg.frame_id] = min(self.sent.get(msg.frame_id, got.sent_ns), got.sent_ns)

    def _finish(self, fs) -> None:
        """Fit one released set and publish its pose (and its credit, lossless)."""
        first = next(iter(fs.items.values()))
        t_fit, cpu_fit = self.clock(), time.thread_time()
        try:
            record = dict(self.fit(fs.frame_id, first.timestamp_ns, fs.items))
        except Exception as exc:  # the fitter is a plug-in; a crash costs one frame, not the service
            log.exception("frame %d: fitting failed", fs.frame_id)
            record = {"frame": fs.frame_id, "timestamp_ns": first.timestamp_ns, "ok": False,
                      "reason": f"fitting failed: {exc.__class__.__name__}: {exc}"[:200]}
        record.setdefault("cameras", len(fs.items))
        if fs.missing:  # which cameras the set went on without (absent, or late beyond the set timeout)
            record.setdefault("missing_cameras", list(fs.missing))
        record.setdefault("fit_ms", 1e3 * (self.clock() - t_fit))
        record.setdefault("fit_cpu_ms", 1e3 * (time.thread_time() - cpu_fit))
        t0 = self.sent.pop(fs.frame_id, None)
        if t0 is not None:
            record["latency_ms"] = (self.wall_ns() - t0) / 1e6
            self.status.latency(record["latency_ms"])
        try:
            pose = PoseRecord.from_dict(record)
        except MessageError as exc:
            pose = PoseRecord.from_dict({"frame": fs.frame_id, "timestamp_ns": first.timestamp_ns,
                                         "ok": False, "reason": f"invalid pose record: {exc}"[:200],
                                         "cameras": len(fs.items)})
        self.pose_pub.put(pose.to_bytes())
        if self.on_pose is not None:
            self.on_pose(pose)
        self._publish_subject()
        if self.credit_pub is not None:
            self.credit_pub.put(CreditMessage(TRACK_CONSUMER, fs.frame_id).to_bytes())
        self.status.count("processed")
        self.status.count("missing_cameras", len(fs.missing))

    def _publish_subject(self) -> None:
        """The fitter's adopted subject on ``keys.subject`` (see the module docstring)."""
        msg = None if self.subject_pub is None else self.fit.auto_subject.message()
        now = self.clock()
        if msg is None or (self._subject_sent is not None and now - self._subject_sent < SUBJECT_REPUBLISH_S):
            return
        self.subject_pub.put(msg.to_bytes())
        self._subject_sent = now
        self.status.count("subject_published")

    def _idle(self, last_input: float | None) -> bool:
        """Input came, none for ``idle_exit_s`` and nothing is pending."""
        return (self.idle_exit_s is not None and last_input is not None
                and self.clock() - last_input > self.idle_exit_s
                and not len(self.asm) and not len(self.inbox) and not (self.haves is not None and len(self.haves)))

    def _raise_priority(self) -> None:
        """Raise the calling thread's priority by ``priority_boost`` nice levels (see the module docstring)."""
        exc = renice_thread(-self.priority_boost) if self.priority_boost > 0 else None
        if exc is not None:
            log.info("fitting thread's priority not raised (%s): it shares the cores as it is", exc)
            self.status.count("priority_refused")

    def run(self) -> dict:
        """Fit until ``max_frames`` poses, ``idle_exit_s`` without input, or ``stop``; returns the counters."""
        done, last_input = 0, None  # idle time counts from the first input
        self._raise_priority()
        try:
            if hasattr(self.fit, "warm_up"):  # compile the fitter's kernels before the first frame, not on it
                self.status.tick(state="warming_up", force=True)
                log.info("fitter warmed up in %.1f s", self.fit.warm_up())
            while not self.stop.is_set() and (self.max_frames is None or done < self.max_frames):
                if self._idle(last_input):
                    break
                self._demand()
                deadline = self.asm.next_deadline()
                wait = 0.05 if deadline is None else min(0.05, max(0.0, deadline - self.clock()))
                if wait_any([self.inbox] if self.haves is None else [self.inbox, self.haves], wait):
                    last_input = self.clock()
                if self.haves is not None:
                    self._take_haves()
                self._take_chamfers()
                for fs in self.asm.pop_ready(self.clock()):
                    if self.planner is not None:  # pipelining: the next set is segmented while this one is fitted
                        self.planner.released(fs.frame_id)
                        self._demand()
                    self._finish(fs)
                    done += 1
                    last_input = self.clock()  # a long fit (re-initialisation) is not idleness
                for fid in [f for f in self.sent if not self.asm.is_pending(f)]:  # bounded by the pending sets
                    del self.sent[fid]
                self.status.tick(**self.gauges())
            return {**self.status.counters, **self.gauges()}
        finally:
            self.close()

    def close(self) -> None:
        """Report 'finished' and close the inboxes and the status reporter."""
        self.status.tick(state="finished", force=True, **self.gauges())
        self.inbox.close()
        if self.haves is not None:
            self.haves.close()
        self.status.close()


def run_track_worker(session: zenoh.Session, keys: Keys, cameras: tuple[str, ...], fit: Fitter, **options) -> dict:
    """``TrackWorker(session, keys, cameras, fit, **options).run()``: the counters when it ends."""
    return TrackWorker(session, keys, cameras, fit, **options).run()
