"""Hull voxels that stay where no body part is: furniture the background model does not hold.

A chair brought in after the background was learnt is foreground in every view, so the coloured
hull holds it in every frame; its voxels attract blobs (a thigh pulled into the seat) and count as
hull the body does not explain.  :class:`StaticVoxels` remembers, per cube of a world lattice, how
consistently the hull was occupied there *and* farther than ``clearance_m`` from the fitted body: an
exponential average of that indicator over frames (rate ``rate``).  Cubes whose average reaches
``threshold`` are *static*: the tracker leaves their voxels out of the expectation and out of the
unexplained volume (they still support the parts, ``tracker.blobs.tracking.hull_support``).  A body
part that the fit leaves behind for a few frames does not become scene: the average needs about
``log(1 − threshold) / log(1 − rate)`` frames in a row to get there, and falls as soon as the
body comes back within ``clearance_m``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["StaticVoxels"]

_BIAS = 1 << 20  # lattice indices within ±2^20 cubes of the origin pack into 21 bits each


def _keys(points: np.ndarray, cell_m: float) -> np.ndarray:
    """Lattice cube of each point (n, 3) as one int64 key (n,)."""
    q = np.floor(np.asarray(points, dtype=float).reshape(-1, 3) / cell_m).astype(np.int64) + _BIAS
    q = np.clip(q, 0, (1 << 21) - 1)
    return (q[:, 0] << 42) | (q[:, 1] << 21) | q[:, 2]


class StaticVoxels:
    """Per lattice cube, the running average of "occupied and away from the body" (module docstring).

    Parameters
    ----------
    cell_m : float
        Lattice cube edge, metres (the hull's finest voxel).
    rate : float in (0, 1]
        Weight of the newest frame in the average.
    threshold : float in (0, 1]
        Average from which a cube is static.
    clearance_m : float
        A voxel counts as away from the body when no part grown by this much contains it.
    """

    def __init__(self, cell_m: float, *, rate: float = 0.05, threshold: float = 0.7,
                 clearance_m: float = 0.1) -> None:
        if not cell_m > 0:
            raise ValueError(f"cell_m: expected > 0, got {cell_m!r}")
        if not 0 < rate <= 1 or not 0 < threshold <= 1:
            raise ValueError(f"rate, threshold: expected in (0, 1], got {rate!r}, {threshold!r}")
        self.cell_m, self.rate, self.threshold = float(cell_m), float(rate), float(threshold)
        self.clearance_m = float(clearance_m)
        self.keys = np.zeros(0, np.int64)   # sorted
        self.score = np.zeros(0)

    def static(self, centres: np.ndarray) -> np.ndarray:
        """Whether each voxel centre (n, 3) lies in a static cube; (n,) bool."""
        k = _keys(centres, self.cell_m)
        if not len(self.keys) or not len(k):
            return np.zeros(len(k), bool)
        pos = np.clip(np.searchsorted(self.keys, k), 0, len(self.keys) - 1)
        return (self.keys[pos] == k) & (self.score[pos] >= self.threshold)

    def update(self, centres: np.ndarray, away: np.ndarray) -> None:
        """One frame: ``centres`` (n, 3) of the hull's voxels, ``away`` (n,) bool: farther than
        ``clearance_m`` from the fitted body.  Every remembered cube decays; the cubes of away
        voxels gain ``rate``; cubes whose average falls below a hundredth are forgotten."""
        hit = np.unique(_keys(np.asarray(centres)[np.asarray(away, bool)], self.cell_m))
        keys = np.union1d(self.keys, hit)
        score = np.zeros(len(keys))
        if len(self.keys):
            score[np.searchsorted(keys, self.keys)] = self.score
        score *= 1.0 - self.rate
        score[np.searchsorted(keys, hit)] += self.rate
        keep = score >= 0.01
        self.keys, self.score = keys[keep], score[keep]
