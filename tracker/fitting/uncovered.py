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

from statistics import median
from typing import Sequence

import numpy as np

__all__ = ["FAILED", "UncoveredWatch", "fit_ok"]

#: the check's name in a pose record's ``failed`` list
FAILED = "uncovered"


def fit_ok(record: dict) -> bool:
    """Whether pose record ``record``'s fit passed the gate: it is ok, or refused by this check alone.

    What a tracker's owner acts on (keeping a refit, a recovery, the effort): the check only reports,
    so that the track goes on as it would without it."""
    failed = record.get("failed")
    return bool(record.get("ok")) or (bool(failed) and set(failed) <= {FAILED})


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
    frames : int
        ``observe`` flags a frame only when this many frames in a row (it included) exceeded the margin
        (a real camera's share is noisy from frame to frame; a lost limb stays lost).
    """

    def __init__(self, *, margin: float, window: int = 30, min_samples: int = 5, frames: int = 1) -> None:
        if not margin > 0 or window < 1 or min_samples < 1 or frames < 1:
            raise ValueError(f"UncoveredWatch: need margin > 0, window >= 1, min_samples >= 1, frames >= 1, got "
                             f"{margin}, {window}, {min_samples}, {frames}")
        self.margin, self.window, self.min_samples = float(margin), int(window), int(min_samples)
        self.frames = int(frames)
        self._shares: dict[str, list[float]] = {}
        self._run = 0  # frames in a row that exceeded the margin

    def observe(self, names: Sequence[str], shares: np.ndarray, *, vouched: bool) -> str:
        """One frame: why it is not ok ("" if it passed).  Every frame counts towards the run of frames
        above the margin; a ``vouched`` frame (one that passed the gate's other checks) is flagged when
        the run reaches ``frames``, and joins the reference when it is not above the margin itself."""
        why = self.check(names, shares)
        self._run = self._run + 1 if why else 0
        if vouched and not why:
            self.update(names, shares)
        return why if vouched and self._run >= self.frames else ""

    def excess(self, names: Sequence[str], shares: np.ndarray) -> np.ndarray:
        """Each camera's share minus its reference, shape (n_cams,) (NaN: no reference yet, or no share).

        ``names``: the cameras, in the order of ``shares`` (n_cams,), each in [0, 1] or NaN."""
        # statistics.median: the same median as numpy's, without its overhead on a few dozen floats
        ref = np.array([median(h) if len(h := self._shares.get(n, ())) >= self.min_samples else np.nan
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
        """Forget every reference and the run (a new subject or body)."""
        self._shares.clear()
        self._run = 0
