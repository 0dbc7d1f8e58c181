"""The track worker with ``[tracker] method = "blobs"``: camera frames in, blob poses and coloured hulls out.

The blob tracker (``tracker.blobs``, BMVC'04) classifies a few pixel samples per voxel against each
camera's background model and keeps their colours, so it needs the colour frames and the background
statistics, not chamfer images.  The smallest path that keeps its cost independent of the image
size: this worker subscribes to the camera frames itself (``cam/<cam>/frame``, any wire encoding)
and owns the background models; no segment worker runs (``service.flow.supervisor.plan_host``), and
this worker holds the ``segment.<cam>`` liveliness tokens that lossless camera workers wait for (it
is what "segments" those cameras).  Frame sets are assembled by :class:`~service.workers.track.TrackWorker`
with ``inputs="frames"``: lossless, every set with credits; live, the newest frame per camera (no
demand: there is no segmentation to schedule).

Background models: a replay camera's from its session (``service.backgrounds``, as the offline
``contourcap track`` does), a live camera's learnt from its first ``learn_frames`` frames (the
studio must be empty at start-up, as for the segment worker).  The first pose comes from the
contour tracker's first frame sets with a person (``tracker.blobs.start.ContourStart``: its silhouette
search, fit and front/back guard), and again after ``reinit_after`` frames in a row that
were not ok.  After every fitted set the coloured hull is published on ``contourcap/<studio>/hull``
(:class:`~service.wire.hull.HullMessage`, newest wins: a slow viewer never holds the tracker).
:meth:`BlobFitter.warm_up` compiles the numba kernels before the first set.
"""

from __future__ import annotations

import logging
import time
from typing import Callable, Mapping, Sequence

import numpy as np
import zenoh

from service.wire.bus import Keys, declare_publisher
from service.wire.hull import HullMessage, hull_message
from service.wire.messages import FrameMessage, MessageError
from service.wire.records import PoseRecord
from service.workers.base import segment_token
from service.workers.track import TrackWorker

__all__ = ["BlobFitter", "run_blob_track_worker"]

log = logging.getLogger("contourcap.worker")


class BlobFitter:
    """The track worker's fitter around ``tracker.blobs.BlobTracker``:
    ``(frame_id, timestamp_ns, {camera: FrameMessage}) -> pose record dict``.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
        The studio's calibrated cameras.
    backgrounds : mapping, optional
        Camera name -> BackgroundModel; cameras without one learn it from their first frames.
    learn_frames : int
        Frames per camera a background is learnt from.
    initial_params : ndarray, shape (n_params,), optional
        The first pose (else the silhouette search on the first set).
    options : BlobOptions, optional
    reinit_after : int
        Not-ok frames in a row after which the tracker starts again from the silhouette search (0: never).
    clock : callable () -> float
        Seconds, for the tracker's latency figures.
    props : sequence of ``tracker.fitting.props.PropBox``, world boxes never body (``tracker.blobs.props``)
    """

    def __init__(self, model, cameras: Sequence, *, backgrounds: Mapping | None = None, learn_frames: int = 30,
                 initial_params=None, options=None, reinit_after: int = 15,
                 clock: Callable[[], float] = time.perf_counter, props: Sequence = ()) -> None:
        from tracker.blobs import BlobOptions

        self.model, self.cameras = model, list(cameras)
        self.backgrounds = dict(backgrounds or {})
        self.learn_frames, self.initial_params = int(learn_frames), initial_params
        self.options = options or BlobOptions()
        self.reinit_after, self.clock = int(reinit_after), clock
        self.props = list(props)
        self.tracker = None
        self.bad_streak = 0
        self.restarts = 0
        self._learning: dict[str, list[np.ndarray]] = {}
        self._hull = None  # (frame_id, timestamp_ns, ColourHull) of the last set that made one

    @classmethod
    def from_session(cls, session, *, model: str = "knossow40", replayed: Sequence[str] = (),
                     **options) -> "BlobFitter":
        """A fitter on ``session``'s calibration, subject (its subject file too) and ``[[prop]]`` boxes;
        ``replayed`` cameras take their background model from the session (``service.backgrounds``), the
        others learn it from their first frames."""
        from service.backgrounds import background_models
        from service.offline import session_model, session_props

        body = session_model(session, model)
        props = session_props(session)
        bgs = background_models(session, list(replayed))[0] if replayed else {}
        return cls(body, list(session.calibration), backgrounds=bgs, props=props, **options)

    def warm_up(self) -> float:
        """Compile the numba kernels the fit runs (``service.offline.warm_up_kernels("blobs")``) or load
        them from the on-disk cache; seconds taken.  The track worker calls it before the first frame
        set, so no frame waits for a compiler."""
        from service.offline import warm_up_kernels

        return warm_up_kernels("blobs")

    def _learn(self, images: Mapping[str, np.ndarray]) -> str | None:
        """Feed cameras still learning their background; a reason while any of those in ``images`` is."""
        from segmentation.background import BackgroundModel

        waiting = []
        for name, img in images.items():
            if name in self.backgrounds:
                continue
            frames = self._learning.setdefault(name, [])
            frames.append(img)
            if len(frames) >= self.learn_frames:
                self.backgrounds[name] = BackgroundModel.from_frames(frames)
                del self._learning[name]
            else:
                waiting.append(f"{name} {len(frames)}/{self.learn_frames}")
        return f"learning the background ({', '.join(waiting)})" if waiting else None

    def _tracker(self, start):
        from tracker.blobs import BlobTracker
        from tracker.blobs.start import ContourStart

        cams = [c for c in self.cameras if c.name in self.backgrounds]
        bgs = dict(self.backgrounds)
        settle = min(30, self.reinit_after) if self.reinit_after > 0 else 30  # handed over before a restart
        return BlobTracker(self.model, cams, bgs, initial_params=start,
                           initialiser=ContourStart(self.model, cams, bgs, max_frames=settle, props=self.props),
                           options=self.options, clock=self.clock, props=self.props)

    def __call__(self, frame_id: int, timestamp_ns: int, frames: Mapping[str, FrameMessage]) -> dict:
        """The pose record of one frame set (``frames``: camera name -> FrameMessage)."""
        base = {"frame": int(frame_id), "timestamp_ns": int(timestamp_ns), "model": self.model.name,
                "method": "blobs", "cameras": len(frames)}
        try:
            images = {name: msg.image() for name, msg in frames.items()}
        except MessageError as exc:
            return {**base, "ok": False, "reason": f"bad frame: {exc}"[:200]}
        learning = self._learn(images)
        if learning is not None:
            return {**base, "ok": False, "reason": learning}
        if self.tracker is not None and self.reinit_after and self.bad_streak >= self.reinit_after:
            self.restarts += 1
            log.info("blob tracker: %d frames not ok, starting again from the silhouette search", self.bad_streak)
            self.tracker, start = None, None
        elif self.tracker is not None and not set(self.backgrounds) <= set(self.tracker.cameras):
            start = self.tracker.params  # a camera learnt its background late: the same pose, one more view
            self.tracker = None
        else:
            start = self.initial_params if not self.restarts else None
        if self.tracker is None:
            self.tracker, self.bad_streak = self._tracker(start), 0
        before = self.tracker.last_hull
        rec = self.tracker.step(frame_id, timestamp_ns, images)
        if self.tracker.last_hull is not before and self.tracker.last_hull is not None:
            self._hull = (int(frame_id), int(timestamp_ns), self.tracker.last_hull)
        self.bad_streak = 0 if rec.get("ok") else self.bad_streak + 1
        return rec

    def hull_message(self, frame_id: int | None = None) -> HullMessage | None:
        """The coloured hull of frame ``frame_id`` (default: the last one made) as a wire message, or None."""
        if self._hull is None or (frame_id is not None and self._hull[0] != frame_id):
            return None
        fid, ts, hull = self._hull
        return hull_message(fid, ts, hull)


def run_blob_track_worker(session: zenoh.Session, keys: Keys, cameras: tuple[str, ...], fit: BlobFitter, *,
                          on_pose: Callable[[PoseRecord], None] | None = None, **options) -> dict:
    """Run a :class:`~service.workers.track.TrackWorker` on the camera frames with ``fit`` (a
    :class:`BlobFitter`), publishing each set's coloured hull; returns the counters when it ends.

    ``options`` are the TrackWorker's (``mode``, ``stop``, ``set_timeout_s``, ``max_frames``, ...).
    """
    tokens = [session.liveliness().declare_token(keys.status(segment_token(c))) for c in cameras]
    hull_pub = declare_publisher(session, keys.hull, mode="live")
    sent = {"hulls": 0}

    def publish(pose: PoseRecord) -> None:
        msg = fit.hull_message(pose.frame) if hasattr(fit, "hull_message") else None
        if msg is not None:
            hull_pub.put(msg.to_bytes())
            sent["hulls"] += 1
        if on_pose is not None:
            on_pose(pose)

    try:
        worker = TrackWorker(session, keys, cameras, fit, inputs="frames", on_pose=publish, **options)
        return {**worker.run(), **sent}
    finally:
        hull_pub.undeclare()
        for token in tokens:
            token.undeclare()
