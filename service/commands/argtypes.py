"""argparse types shared by the sub-commands: a bad value is refused by argparse (exit 2, one line)."""

from __future__ import annotations

import argparse
import math

__all__ = ["positive_float"]


def positive_float(text: str) -> float:
    """A finite number > 0 (frame rates, durations): ``--fps 0``, ``nan`` or ``-1`` are refused."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value
