"""argparse types shared by the sub-commands: a bad value is refused by argparse (exit 2, one line)."""

from __future__ import annotations

import argparse
import math

__all__ = ["positive_float", "duration_s"]


def positive_float(text: str) -> float:
    """A finite number > 0 (frame rates, durations): ``--fps 0``, ``nan`` or ``-1`` are refused."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def duration_s(text: str) -> float:
    """A duration in seconds: ``2``, ``2s``, ``1.5 s``, ``500ms``, ``1m`` (finite, > 0)."""
    t = text.strip().lower().replace(" ", "")
    scale = 1.0
    for suffix, factor in (("ms", 1e-3), ("s", 1.0), ("m", 60.0)):
        if t.endswith(suffix):
            t, scale = t[: -len(suffix)], factor
            break
    try:
        return positive_float(t) * scale
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a duration such as 2s or 500ms, got {text!r}") from None
