"""Pose records placed on the session's frame grid, and their joint centres as marker arrays.

Every file output keeps time: row k is frame id ``first + k`` at ``k / fps`` seconds, whatever frame
ids the records skip (a live take's ids jump where the tracker fitted fewer frames).  Rows without an
ok record are gaps.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from service.outputs.posefile import ExportError, fps_from_records
from service.wire.records import PoseRecord

MAX_ROWS = 5_000_000
"""Largest frame-id span a file output fills (about 46 h at 30 fps)."""


@dataclass(frozen=True)
class Timeline:
    """Records on a regular frame grid.

    Attributes
    ----------
    frames : ndarray of int, shape (n_rows,)
        Frame ids ``first .. last``.
    record : ndarray of int, shape (n_rows,)
        Index into the records of each row's record, −1 where no record has that frame id.
    ok : ndarray of bool, shape (n_rows,)
        Row has an ok record.
    fps : float
        Frames per second of the grid.
    """

    frames: np.ndarray
    record: np.ndarray
    ok: np.ndarray
    fps: float

    @property
    def n_rows(self) -> int:
        return int(self.frames.size)

    @property
    def times_s(self) -> np.ndarray:
        """Seconds since the first frame, shape (n_rows,)."""
        return (self.frames - self.frames[0]) / self.fps


def make_timeline(records: Sequence[PoseRecord], *, fps: float | None = None, where: str = "poses") -> Timeline:
    """The frame grid of ``records`` (frame ids must increase); ``fps`` default: from the timestamps."""
    if not records:
        raise ExportError(f"{where}: no pose records")
    ids = np.array([r.frame for r in records], dtype=np.int64)
    bad = np.flatnonzero(np.diff(ids) <= 0)
    if bad.size:
        i = int(bad[0]) + 1
        raise ExportError(f"{where}: frame ids must increase (record {i + 1} has frame {ids[i]} after "
                          f"{ids[i - 1]}); split files that hold several takes")
    span = int(ids[-1] - ids[0]) + 1
    if span > MAX_ROWS:
        raise ExportError(f"{where}: frame ids span {span} frames (more than {MAX_ROWS})")
    if fps is None:
        fps = fps_from_records(records)
    if not (fps > 0 and np.isfinite(fps)):
        raise ExportError(f"{where}: frame rate must be positive, got {fps}")
    frames = np.arange(ids[0], ids[-1] + 1)
    rec = np.full(span, -1, dtype=np.int64)
    rec[ids - ids[0]] = np.arange(len(records))
    ok_rec = np.array([r.ok for r in records], dtype=bool)
    ok = np.zeros(span, dtype=bool)
    ok[ids - ids[0]] = ok_rec
    return Timeline(frames, rec, ok, float(fps))


def marker_names(records: Sequence[PoseRecord], where: str = "poses") -> list[str]:
    """Joint names of the first ok record with joints, in its order (ExportError if none has joints)."""
    for r in records:
        joints = r.get("joints")
        if r.ok and joints:
            return list(joints)
    raise ExportError(f"{where}: no ok pose record has joints")


def marker_array(records: Sequence[PoseRecord], tl: Timeline, names: Sequence[str], *,
                 axes: np.ndarray, scale: float) -> np.ndarray:
    """Joint centres per row, shape (n_rows, n_markers, 3), in output axes and units; NaN for gaps.

    Parameters
    ----------
    axes : ndarray, shape (3, 3)
        Output axes (see :mod:`tracker.body.joint_frames`).
    scale : float
        Output units per metre (1000 for mm).
    """
    X = np.full((tl.n_rows, len(names), 3), np.nan)
    for row in np.flatnonzero(tl.ok):
        joints = records[tl.record[row]].get("joints") or {}
        for j, name in enumerate(names):
            p = joints.get(name)
            if p is not None:
                X[row, j] = p
    return (X @ np.asarray(axes, float).T) * scale
