"""The three workers under one import path: camera -> frames, segment -> chamfer images, track -> poses.

Each ``run_*`` function takes an open zenoh session, the studio :class:`~service.wire.bus.Keys`, its
sources or processing callable, and a ``stop`` event; it returns a dict of counters when ``stop`` is
set or its input ends.  The workers are :mod:`~service.workers.camera`, :mod:`~service.workers.segment`
and :mod:`~service.workers.track`; what they share is in :mod:`~service.workers.base`.  Processes,
argparse and signals live in ``service/commands/worker.py``.
"""

from __future__ import annotations

from service.workers.base import TRACK_CONSUMER, Fitter, Segmenter, WorkerError, segment_token
from service.workers.camera import CameraWorker, EpochPacer, run_camera_worker
from service.workers.segment import SegmentWorker, run_segment_worker
from service.workers.track import LOSSLESS_SET_TIMEOUT_S, TrackWorker, run_track_worker

__all__ = [
    "TRACK_CONSUMER", "Fitter", "Segmenter", "WorkerError", "segment_token", "CameraWorker", "EpochPacer",
    "run_camera_worker", "SegmentWorker", "run_segment_worker", "LOSSLESS_SET_TIMEOUT_S", "TrackWorker",
    "run_track_worker",
]  # fmt: skip
