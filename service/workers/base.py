"""What the three workers share: their error, the seams they call and the names they agree on.

Seams (adapted to the real components in :mod:`service.workers.components`):

- ``Segmenter``: ``(frame: FrameMessage, image_bgr (h, w, 3) uint8) -> ChamferMessage | None``
  (None: nothing to publish yet, e.g. still learning the background)
- ``Fitter``: ``(frame_id, timestamp_ns, chamfer: dict[camera, ChamferMessage]) -> dict`` (a DESIGN.md
  pose record, ``ok``/``reason`` included)

Latency: the camera worker attaches its wall-clock publish time (8 bytes) to each frame, the segment
worker forwards it, and the tracker reports ``latency_ms = now - earliest capture time of the set``
(across hosts this relies on NTP/PTP-synchronised clocks).
"""

from __future__ import annotations

import os
import threading
from typing import Callable

from service.wire.messages import ChamferMessage, FrameMessage

__all__ = ["WorkerError", "Segmenter", "Fitter", "TRACK_CONSUMER", "renice_thread", "segment_token"]

Segmenter = Callable[[FrameMessage, object], ChamferMessage]
Fitter = Callable[[int, int, dict], dict]
TRACK_CONSUMER = "track"


class WorkerError(RuntimeError):
    """A worker could not go on (camera lost, peers unreachable, no credit): its process must exit
    non-zero so that the supervisor restarts it (a clean return means "finished", never restarted)."""


def segment_token(camera: str) -> str:
    """Liveliness name of "camera ``camera`` is being segmented" (lossless cameras wait for it)."""
    return f"segment.{camera}"


def renice_thread(delta: int) -> OSError | None:
    """Change the calling thread's niceness by ``delta`` levels (negative: a higher priority); the
    refusal, or None (also where the OS has no per-thread niceness: nothing changed)."""
    if delta == 0 or not hasattr(os, "setpriority"):
        return None
    tid = threading.get_native_id()  # Linux: PRIO_PROCESS of a thread id is that thread's niceness
    try:
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + int(delta))
    except OSError as exc:
        return exc
    return None
