"""Segment a session's frames once, for the tracker benchmarks (``bench/tracker.py``, ``bench/live_gaps.py``)."""

from __future__ import annotations

import time

import numpy as np

from capture.replay import iter_frame_sets
from segmentation.pipeline import segment_frame
from service.offline import background_models


def segment_session(session, frames: int, cpu_ms: list | None = None):
    """Chamfer images and silhouettes per frame: list of (frame_id, ts, {cam: chamfer}, {cam: sil}), and
    the median wall milliseconds per camera frame; ``cpu_ms`` (optional) receives each frame set's
    segmentation CPU time."""
    names = list(session.camera_names)
    bgs, _ = background_models(session, names)
    out, ms = [], []
    for fid, group in iter_frame_sets(session, frames=range(0, frames)):
        # this thread's CPU: the video decoder's own threads (which may decode ahead) are not segmentation
        t0, c0 = time.perf_counter(), time.thread_time()
        segs = {n: segment_frame(bgs[n], f.image) for n, f in group.items()}
        ms.append(1e3 * (time.perf_counter() - t0) / max(len(group), 1))
        if cpu_ms is not None:
            cpu_ms.append(1e3 * (time.thread_time() - c0))
        ts = next(iter(group.values())).timestamp_ns
        out.append((fid, ts, {n: s.chamfer for n, s in segs.items()}, {n: s.silhouette for n, s in segs.items()}))
    return out, float(np.median(ms))
