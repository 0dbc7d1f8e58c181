"""The 1€ filter (Casiez, Roussel & Vogel, CHI 2012) for smoothing pose streams for their consumers.

A first-order low-pass filter whose cutoff rises with the signal's speed: slow motion (where jitter
shows) is smoothed hard, fast motion passes with little lag.  Per sample of period ``dt`` seconds::

    α(fc) = 1 / (1 + τ / dt),   τ = 1 / (2π fc)
    dx̂ = α(d_cutoff) · (x − x̂_prev) / dt + (1 − α(d_cutoff)) · dx̂_prev
    fc  = min_cutoff + β · |dx̂|
    x̂  = α(fc) · x + (1 − α(fc)) · x̂_prev

applied independently to every coordinate of an array (each joint coordinate, each pose parameter).
The first sample after construction or :meth:`OneEuroFilter.reset` passes through unchanged.
Pure numpy, no I/O.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["OneEuroFilter", "parse_one_euro", "unwrap_rotation_vector", "DEFAULT_MIN_CUTOFF_HZ", "DEFAULT_BETA"]

DEFAULT_MIN_CUTOFF_HZ = 1.0
"""Cutoff at rest, Hz."""
DEFAULT_BETA = 10.0
"""Cutoff increase per unit of speed, Hz per (unit/s): metres for joints, radians for angles."""
DEFAULT_D_CUTOFF_HZ = 1.0


def _alpha(cutoff_hz: np.ndarray | float, dt: float) -> np.ndarray | float:
    tau = 1.0 / (2.0 * math.pi * cutoff_hz)
    return 1.0 / (1.0 + tau / dt)


class OneEuroFilter:
    """A 1€ filter over arrays of a fixed shape (every element filtered on its own).

    Parameters
    ----------
    min_cutoff : float
        Cutoff frequency at zero speed, Hz (> 0).
    beta : float
        Speed coefficient, Hz per (unit / s) (≥ 0).
    d_cutoff : float
        Cutoff of the speed estimate, Hz (> 0).
    """

    def __init__(self, min_cutoff: float = DEFAULT_MIN_CUTOFF_HZ, beta: float = DEFAULT_BETA,
                 d_cutoff: float = DEFAULT_D_CUTOFF_HZ) -> None:
        if not (min_cutoff > 0 and math.isfinite(min_cutoff)):
            raise ValueError(f"one-euro: min_cutoff must be a positive number of Hz, got {min_cutoff}")
        if not (beta >= 0 and math.isfinite(beta)):
            raise ValueError(f"one-euro: beta must be >= 0, got {beta}")
        if not (d_cutoff > 0 and math.isfinite(d_cutoff)):
            raise ValueError(f"one-euro: d_cutoff must be a positive number of Hz, got {d_cutoff}")
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self._x: np.ndarray | None = None
        self._dx: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the past: the next sample passes through unchanged."""
        self._x = self._dx = None

    @property
    def primed(self) -> bool:
        """Whether the filter holds a previous sample."""
        return self._x is not None

    def __call__(self, x: np.ndarray, dt: float) -> np.ndarray:
        """Filter one sample.

        Parameters
        ----------
        x : array_like
            The sample (any shape; the same shape at every call until :meth:`reset`).
        dt : float
            Seconds since the previous sample (> 0).

        Returns
        -------
        ndarray
            The filtered sample, same shape as ``x``.
        """
        x = np.array(x, dtype=float)
        if self._x is None or self._x.shape != x.shape:
            self._x, self._dx = x, np.zeros_like(x)
            return x.copy()
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"one-euro: dt must be positive, got {dt}")
        dx = (x - self._x) / dt
        self._dx = self._dx + _alpha(self.d_cutoff, dt) * (dx - self._dx)
        a = _alpha(self.min_cutoff + self.beta * np.abs(self._dx), dt)
        self._x = self._x + a * (x - self._x)
        return self._x.copy()


def parse_one_euro(spec: str) -> tuple[float, float] | None:
    """``"one-euro"`` or ``"one-euro:MIN_CUTOFF,BETA"`` -> (min_cutoff Hz, beta); ``"off"``/``"none"`` -> None.

    Raises ValueError with the accepted forms for anything else.
    """
    text = spec.strip().lower()
    if text in ("off", "none", "0", "no"):
        return None
    name, _, rest = text.partition(":")
    if name not in ("one-euro", "1euro", "one_euro"):
        raise ValueError(f"--smooth: expected 'one-euro', 'one-euro:MIN_CUTOFF,BETA' or 'off', got {spec!r}")
    if not rest:
        return DEFAULT_MIN_CUTOFF_HZ, DEFAULT_BETA
    try:
        mc, beta = (float(v) for v in rest.split(","))
    except ValueError:
        raise ValueError(f"--smooth: expected one-euro:MIN_CUTOFF,BETA (two numbers), got {spec!r}") from None
    OneEuroFilter(mc, beta)  # validates
    return mc, beta


def unwrap_rotation_vector(r: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The rotation vector equivalent to ``r`` (same rotation) nearest to ``reference``.

    A rotation by θ about unit axis a is also θ − 2π about a; near θ = π the principal vector flips
    sign.  Filtering rotation vectors coordinate by coordinate needs them continuous in time.

    Parameters
    ----------
    r, reference : ndarray, shape (3,)
        Rotation vectors, radians.
    """
    r = np.asarray(r, dtype=float)
    theta = float(np.linalg.norm(r))
    if theta < 1e-9:
        return r.copy()
    axis = r / theta
    k = np.round((float(np.dot(reference, axis)) - theta) / (2 * math.pi))
    cands = [(theta + 2 * math.pi * (k + d)) * axis for d in (-1, 0, 1)]
    return min(cands, key=lambda c: float(np.sum((c - reference) ** 2)))
