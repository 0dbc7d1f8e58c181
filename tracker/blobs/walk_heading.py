"""A trunk-yaw cue that is not the arms: people mostly face where they walk.

:class:`WalkHeading` keeps the fitted pelvis's recent horizontal positions (a window of
``window_s`` seconds of frame timestamps) and gives, for a pose, the turn about the vertical that
brings the pelvis's facing direction (``tracker.search.mirror.pelvis_heading``) a fraction of the
way to the direction of walking.  The fraction is ``gain`` times a speed weight that is 0 at or
below ``speed_min`` (standing, stepping, turning on the spot: no cue) and 1 at or above
``speed_full``, linear between.  :func:`walk_turn` is the pure rule, :class:`WalkHeading` its state.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from tracker.body.model import ROOT_TRANSLATION, BodyModel
from tracker.search.mirror import pelvis_heading


def walk_turn(facing_xy, velocity_xy, *, gain: float, speed_min: float, speed_full: float,
              max_rad: float = np.pi) -> float:
    """Turn (radians, about +z) a fraction of the way from ``facing_xy`` to ``velocity_xy``.

    Parameters
    ----------
    facing_xy : array-like, shape (2,)
        Horizontal direction the pelvis faces (need not be unit; zeros: no cue).
    velocity_xy : array-like, shape (2,)
        Horizontal pelvis velocity, metres per second.
    gain : float
        Fraction of the angle turned at full speed, in [0, 1].
    speed_min, speed_full : float
        Speeds (m/s) where the weight starts from 0 and reaches 1 (``speed_full > speed_min``).
    max_rad : float
        Largest angle between facing and walking that is corrected; beyond it (walking sideways or
        backwards, or a velocity the fit made up) no turn.

    Returns
    -------
    float
        The turn in (-pi, pi] times the weight; 0 when slow or when ``facing_xy`` is zero.
    """
    f = np.asarray(facing_xy, dtype=float)
    v = np.asarray(velocity_xy, dtype=float)
    speed = float(np.hypot(*v))
    w = np.clip((speed - speed_min) / (speed_full - speed_min), 0.0, 1.0)
    if w <= 0 or not np.any(f):
        return 0.0
    d = np.arctan2(v[1], v[0]) - np.arctan2(f[1], f[0])
    d = float(np.angle(np.exp(1j * d)))
    if abs(d) > max_rad:
        return 0.0
    return float(gain * w * d)


class WalkHeading:
    """Recent pelvis positions and the walking-direction turn (module docstring).

    Parameters
    ----------
    model : BodyModel
    gain : float
        :func:`walk_turn`'s gain, in [0, 1] (0: never turns).
    speed_min, speed_full : float
        :func:`walk_turn`'s speeds, m/s.
    window_s : float
        Time span of the velocity estimate, seconds (> 0).
    max_rad : float
        :func:`walk_turn`'s largest corrected angle, radians.
    """

    def __init__(self, model: BodyModel, *, gain: float, speed_min: float, speed_full: float,
                 window_s: float, max_rad: float = np.pi) -> None:
        if not 0.0 <= gain <= 1.0:
            raise ValueError(f"gain: expected a value in [0, 1], got {gain!r}")
        if not 0.0 <= speed_min < speed_full:
            raise ValueError(f"speed_min, speed_full: expected 0 <= speed_min < speed_full, got "
                             f"{speed_min!r}, {speed_full!r}")
        if not window_s > 0:
            raise ValueError(f"window_s: expected > 0, got {window_s!r}")
        self.model = model
        self.gain, self.speed_min, self.speed_full, self.window_s = gain, speed_min, speed_full, window_s
        self.max_rad = float(max_rad)
        self._t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
        self._track: deque = deque()

    def reset(self) -> None:
        """Forget the positions (a lost track: the next velocity starts afresh)."""
        self._track.clear()

    def velocity(self) -> np.ndarray:
        """Horizontal pelvis velocity (2,) m/s over the window; zeros with under two positions."""
        if len(self._track) < 2:
            return np.zeros(2)
        (t0, p0), (t1, p1) = self._track[0], self._track[-1]
        return (p1 - p0) / (t1 - t0) if t1 > t0 else np.zeros(2)

    def add(self, t_s: float, params: np.ndarray | None = None, *, point_xy=None) -> None:
        """Record the fitted pose's pelvis (``params``), or a body point ``point_xy`` (2,) metres such as
        the hull's centroid, at time ``t_s`` (seconds); drop positions older than the window."""
        xy = (np.asarray(params, dtype=float)[self._t_idx[:2]] if point_xy is None
              else np.asarray(point_xy, dtype=float).reshape(2))
        self._track.append((float(t_s), xy.copy()))
        while len(self._track) > 2 and self._track[-1][0] - self._track[1][0] >= self.window_s:
            self._track.popleft()

    def turn(self, params: np.ndarray) -> float:
        """Turn (radians about +z) this pose's pelvis should make toward the walking direction."""
        return walk_turn(pelvis_heading(self.model, params), self.velocity(), gain=self.gain,
                         speed_min=self.speed_min, speed_full=self.speed_full, max_rad=self.max_rad)
