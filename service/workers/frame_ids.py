"""Frame ids of cameras without a trigger box."""

from __future__ import annotations

from typing import Callable

from service.config import ConfigError

__all__ = ["free_run_frame_ids"]


def free_run_frame_ids(fps: float) -> Callable[[int], int]:
    """Frame id of a timestamp: the index of the nearest ``1/fps`` tick of the wall clock.

    The wall clock (``time.time_ns``) is NTP/PTP-synchronised across hosts, so frames of separately
    started (or restarted) camera processes share ids when taken at about the same time.  Counting
    from 0 per process instead misaligned the cameras and, after a restart, made every frame of the
    restarted camera "late" in live mode for good.

    Parameters
    ----------
    fps : float
        Tick rate (frames per second), > 0.

    Returns
    -------
    callable (timestamp_ns) -> int
    """
    if not (fps > 0):
        raise ConfigError(f"fps must be positive to number frames, got {fps!r}")
    period_ns = int(round(1e9 / fps))
    return lambda timestamp_ns: (int(timestamp_ns) + period_ns // 2) // period_ns
