"""Signal handling of worker and supervisor processes."""

from __future__ import annotations

import signal
import threading

__all__ = ["stop_on_signals"]


def stop_on_signals(stop: threading.Event) -> None:
    """SIGINT/SIGTERM set ``stop`` (the loops then finish cleanly); call from the main thread."""
    def handler(signum, frame):
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)
