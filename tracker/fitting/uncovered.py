"""The unexplained-boundary check of the quality gate: a limb lost against the body, per camera.

A fit whose limb has left its silhouette can still pass the gate's RMS, inside and mean-IoU limits:
the lost limb lies on the silhouette's inner edges and fits them well, the rest of the body keeps the
mean figures up.  What it cannot hide is the outline of the true limb, left unexplained by the model
in the cameras that see it beside the body.  ``UncoveredWatch`` keeps, per camera, the share of the
observed evidence the model left unexplained (the tracker gives it the share of each camera's
silhouette-boundary samples far from the model: ``CostTerms.coverage_per_camera``) on the recent
frames the track vouched for, and flags a frame whose share in some camera exceeds that camera's
median by more than a margin.

Per camera because the cameras differ and a mean over them dilutes the one camera that sees the lost
limb; relative to the track's own frames because the level is set by the body and the segmentation
(a subject unlike the model, props cutting the silhouette), not by the pose.  The check only
reports: the track goes on from the gate's own verdict (``tracker.fitting.tracking.Tracker``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["UncoveredWatch"]


class UncoveredWatch:
    """Per-camera reference of the uncovered silhouette share, and the check of a frame against it.

    Parameters
    ----------
    margin : float
        A camera's share above its reference by more than this (a fraction, as the shares) flags
        the frame.
    window : int
        Frames kept per camera; the reference is their median.
    min_samples : int
        A camera with fewer frames has no reference and is not checked.
    """

    def __init__(self, *, margin: float, window: int = 30, min_samples: int = 5) -> None:
        if not margin > 0 or window < 1 or min_samples < 1:
            raise ValueError(f"UncoveredWatch: need margin > 0, window >= 1, min_samples >= 1, got "
                             f"{margin}, {window}, {min_samples}")
        self.margin, self.window, self.min_samples = float(margin), int(window), int(min_samples)
        self._shares: dict[str, list[float]] = {}

    def excess(self, names: Sequence[str], shares: np.ndarray) -> np.ndarray:
        """Each camera's share minus its reference, shape (n_cams,) (NaN: no reference yet, or no share).

        ``names``: the cameras, in the order of ``shares`` (n_cams,), each in [0, 1] or NaN."""
        ref = np.array([np.median(h) if len(h := self._shares.get(n, ())) >= self.min_samples else np.nan
                        for n in names], dtype=float)
        return np.asarray(shares, dtype=float) - ref

    def check(self, names: Sequence[str], shares: np.ndarray) -> str:
        """Why the frame is not ok ("" if it passed): the cameras whose share exceeds their reference
        by more than ``margin``."""
        ex = self.excess(names, shares)
        over = np.flatnonzero(ex > self.margin)
        if not over.size:
            return ""
        worst = ", ".join(f"{names[k]} {100 * shares[k]:.0f}% (usual {100 * (shares[k] - ex[k]):.0f}%)" for k in over)
        return f"boundary unexplained: {worst}"

    def update(self, names: Sequence[str], shares: np.ndarray) -> None:
        """Add a frame the track vouches for to each camera's reference."""
        for n, s in zip(names, np.asarray(shares, dtype=float)):
            if np.isfinite(s):
                self._shares[n] = (self._shares.get(n, []) + [float(s)])[-self.window:]

    def reset(self) -> None:
        """Forget every reference (a new subject or body)."""
        self._shares.clear()
