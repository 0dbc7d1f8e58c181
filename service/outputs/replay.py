"""Replaying a recorded take in real time (or faster/slower), optionally looped."""

from __future__ import annotations

import threading
import time
from typing import Iterator, Sequence

from service.wire.records import PoseRecord


def iter_replay(records: Sequence[PoseRecord], fps: float, *, rate: float = 1.0, loop: bool = False,
                stop: threading.Event | None = None) -> Iterator[tuple[PoseRecord, float]]:
    """Yield ``(record, take_time_s)`` paced by frame ids: frame k at ``(k - first) / fps / rate`` seconds
    after the start (a loop restarts one frame after the last).  ``take_time_s`` keeps increasing across
    loops.  Stops early when ``stop`` is set.

    Parameters
    ----------
    fps : float
        The take's frame rate, frames per second.
    rate : float
        Playback speed (2.0: twice real time).
    """
    if not records:
        return
    if not (fps > 0 and rate > 0):
        raise ValueError(f"replay: fps and rate must be positive, got {fps}, {rate}")
    first = records[0].frame
    period = (records[-1].frame - first + 1) / fps
    start = time.monotonic()
    offset = 0.0
    while True:
        for rec in records:
            t = offset + (rec.frame - first) / fps
            delay = start + t / rate - time.monotonic()
            if delay > 0:
                if stop is not None:
                    if stop.wait(delay):
                        return
                else:
                    time.sleep(delay)
            elif stop is not None and stop.is_set():
                return
            yield rec, t
        if not loop:
            return
        offset += period
