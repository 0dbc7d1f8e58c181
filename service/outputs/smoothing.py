"""The 1€ filter (:mod:`tracker.body.filters`) applied to a stream of pose records, for their consumers.

Each joint coordinate and each pose parameter is filtered on its own; the time step is the frame-id
step over the session's frame rate (in live mode, where the rate is not known: the timestamp step); a record that is not ok resets the filter (the next ok record
passes unchanged), as does a change of the joint set or parameter count.  The root rotation vector
(``params[3:6]``, :mod:`tracker.body.kinematics`) is unwrapped to the equivalent vector nearest the previous
one before filtering.  The records themselves are never changed: :meth:`RecordSmoother.update` returns
new ``joints`` and ``params``.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from service.wire.records import PoseRecord
from tracker.body.filters import OneEuroFilter, unwrap_rotation_vector

ROOT_ROTATION = slice(3, 6)


class RecordSmoother:
    """1€ smoothing of successive pose records.

    Parameters
    ----------
    min_cutoff, beta : float
        1€ parameters (Hz; Hz per unit/s).
    fps : float, optional
        The session's frame rate (frames per second), for the time step between frame ids; None: the
        step of the records' ``timestamp_ns``.
    """

    def __init__(self, min_cutoff: float, beta: float, fps: float | None) -> None:
        if fps is not None and not (fps > 0):
            raise ValueError(f"smoothing: fps must be positive, got {fps}")
        self.fps = None if fps is None else float(fps)
        self._last_ts: int | None = None
        self._joints = OneEuroFilter(min_cutoff, beta)
        self._params = OneEuroFilter(min_cutoff, beta)
        self._names: tuple | None = None
        self._last_frame: int | None = None
        self._last_params: np.ndarray | None = None

    def reset(self) -> None:
        self._joints.reset()
        self._params.reset()
        self._names = self._last_frame = self._last_params = self._last_ts = None

    def update(self, rec: PoseRecord) -> tuple[dict[str, list[float]] | None, list[float] | None]:
        """Smoothed ``(joints, params)`` of an ok record (None for what it lacks); a not-ok record resets
        the filter and returns ``(None, None)``."""
        if not rec.ok:
            self.reset()
            return None, None
        if self._last_frame is not None and rec.frame <= self._last_frame:
            self.reset()  # a new take or a replay loop
        if self._last_frame is None:
            dt = 1.0  # unused: the first sample passes through
        elif self.fps is not None:
            dt = (rec.frame - self._last_frame) / self.fps
        elif self._last_ts is not None and rec.timestamp_ns > self._last_ts:
            dt = (rec.timestamp_ns - self._last_ts) / 1e9
        else:
            self.reset()
            dt = 1.0
        self._last_frame, self._last_ts = rec.frame, rec.timestamp_ns
        joints = rec.get("joints") or None
        out_j = None
        if joints:
            names = tuple(joints)
            if names != self._names:
                self._joints.reset()
                self._names = names
            X = self._joints(np.array([joints[n] for n in names], float), dt)
            out_j = {n: X[i].tolist() for i, n in enumerate(names)}
        params = rec.get("params")
        out_p = None
        if params:
            p = np.array(params, float)
            if self._last_params is not None and self._last_params.shape == p.shape and p.size >= 6:
                p[ROOT_ROTATION] = unwrap_rotation_vector(p[ROOT_ROTATION], self._last_params[ROOT_ROTATION])
            q = self._params(p, dt)
            self._last_params = q
            out_p = q.tolist()
        return out_j, out_p


def smooth_records(records: Sequence[PoseRecord], min_cutoff: float, beta: float, fps: float) -> list[PoseRecord]:
    """Copies of ``records`` whose ``joints`` and ``params`` are smoothed (not-ok records unchanged)."""
    sm = RecordSmoother(min_cutoff, beta, fps)
    out = []
    for rec in records:
        joints, params = sm.update(rec)
        if not rec.ok:
            out.append(rec)
            continue
        fields = dict(rec.fields)
        if joints is not None:
            fields["joints"] = joints
        if params is not None:
            fields["params"] = params
        out.append(PoseRecord.from_dict(fields))
    return out
