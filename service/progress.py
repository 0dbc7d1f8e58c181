"""One progress line for long CLI work: done/total, rate, ETA, a label.

The stream is looked up when written (``sys.stderr`` by default), never bound at import time, so a
replaced or closed stream is never written to by a later run.  The clock is injected for tests.
Use it as a callback, ``progress(done, total, label)``, or by steps, ``progress.advance(label=...)``.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, TextIO

__all__ = ["Progress"]


def _clock_text(seconds: float) -> str:
    """``MM:SS``, or ``H:MM:SS`` from an hour on (``%M:%S`` alone wraps every hour)."""
    m, s = divmod(int(round(max(seconds, 0.0))), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m:02d}:{s:02d}"


class Progress:
    """A one-line progress bar with rate and ETA, redrawn at most every ``min_interval_s``.

    Parameters
    ----------
    total : int, optional
        Items expected (None: no bar, no ETA).
    unit : str
        Name of an item in the line.
    enabled : bool
        False draws nothing.
    stream : text stream, optional
        Where to draw (default ``sys.stderr`` at draw time).
    clock : callable () -> float
        Seconds.
    width : int
        Bar width (characters).
    min_interval_s : float
        Least time between redraws (seconds).
    """

    def __init__(self, total: int | None = None, *, unit: str = "frames", enabled: bool = True,
                 stream: TextIO | None = None, clock: Callable[[], float] = time.monotonic,
                 width: int = 30, min_interval_s: float = 0.2) -> None:  # fmt: skip
        self.total, self.unit, self.enabled, self.width = total, unit, enabled, width
        self._stream, self.clock, self.min_interval_s = stream, clock, min_interval_s
        self.done = 0
        self.start = clock()
        self._last = -float("inf")
        self._open = False

    @property
    def stream(self) -> TextIO | None:
        """The stream drawn on."""
        return self._stream if self._stream is not None else sys.stderr

    def __call__(self, done: int, total: int | None = None, label: str = "") -> None:
        """Set the items done (and the total) and redraw; ``label`` prefixes the line."""
        self.done = done
        if total is not None:
            self.total = total
        self._draw(label)

    def advance(self, n: int = 1, *, label: str = "") -> None:
        """``n`` more items done; redraw."""
        self.done += n
        self._draw(label)

    def _draw(self, label: str) -> None:
        stream = self.stream
        now = self.clock()
        if not self.enabled or stream is None:
            return
        if now - self._last < self.min_interval_s and self.done != self.total:
            return
        self._last = now
        rate = self.done / max(now - self.start, 1e-9)
        if self.total:
            frac = min(self.done / self.total, 1.0)
            fill = int(frac * self.width)
            eta = (self.total - self.done) / rate if rate > 0 else None
            eta_txt = _clock_text(eta) if eta is not None and eta < 360000 else "--:--"
            line = f"[{'#' * fill}{'.' * (self.width - fill)}] {self.done}/{self.total} {self.unit} {rate:6.1f}/s ETA {eta_txt} {label}"
        else:
            line = f"{self.done} {self.unit} {rate:6.1f}/s {label}"
        stream.write("\r" + line[:110].ljust(110))
        stream.flush()
        self._open = True

    def close(self) -> None:
        """End the line (the next output starts on a new one)."""
        stream = self.stream
        if self._open and stream is not None:
            stream.write("\n")
            stream.flush()
        self._open = False
