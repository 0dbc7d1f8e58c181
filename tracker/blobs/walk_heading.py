"""A trunk-yaw cue that is not the arms: people mostly face where they walk.

:class:`WalkHeading` keeps the fitted pelvis joint's recent positions (a window of ``window_s``
seconds of frame timestamps) and gives, for a pose, the turn about the vertical that brings the
pelvis's facing direction (``tracker.search.mirror.pelvis_heading``) a fraction of the way to the
direction of walking.  The velocity is the least-squares slope of the horizontal positions over the
window.  The fraction is ``gain`` times a speed weight that is 0 at or below ``speed_min``
(standing, stepping, turning on the spot: no cue) and 1 at or above ``speed_full``, linear between,
and 0 while the pelvis is below ``upright`` × its standing height (a crouch, sitting, bending: the
pelvis moves over feet that stay, which is not walking).  The points are the pelvis *joint*, not
the root translation parameters: the root rotates about the model's origin on the floor, so
leaning moves those parameters, not the pelvis.  :func:`walk_turn` is the pure rule,
:class:`WalkHeading` its state.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import BodyModel
from tracker.search.mirror import pelvis_heading


def speed_weight(velocity_xy, *, speed_min: float, speed_full: float) -> float:
    """Weight in [0, 1] of a horizontal velocity (2,) m/s: 0 up to ``speed_min``, 1 from ``speed_full``
    (m/s, ``speed_full > speed_min``), linear between."""
    speed = float(np.hypot(*np.asarray(velocity_xy, dtype=float).reshape(2)))
    return float(np.clip((speed - speed_min) / (speed_full - speed_min), 0.0, 1.0))


def walk_turn(facing_xy, velocity_xy, *, gain: float, speed_min: float, speed_full: float,
              max_rad: float = np.pi, dead_rad: float = 0.0) -> float:
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
    dead_rad : float
        Dead band: the angle's first ``dead_rad`` radians are not turned (walking on a curve, the
        pelvis's swing in a stride), ``0 <= dead_rad < max_rad``.

    Returns
    -------
    float
        (|angle| - ``dead_rad``) with the angle's sign (angle in (-pi, pi]) times ``gain`` and the weight;
        0 when slow, inside the dead band, beyond ``max_rad`` or when ``facing_xy`` is zero.
    """
    f = np.asarray(facing_xy, dtype=float)
    v = np.asarray(velocity_xy, dtype=float)
    w = speed_weight(v, speed_min=speed_min, speed_full=speed_full)
    if w <= 0 or not np.any(f):
        return 0.0
    d = np.arctan2(v[1], v[0]) - np.arctan2(f[1], f[0])
    d = float(np.angle(np.exp(1j * d)))
    if abs(d) > max_rad or abs(d) <= dead_rad:
        return 0.0
    return float(gain * w * np.sign(d) * (abs(d) - dead_rad))


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
    max_rad, dead_rad : float
        :func:`walk_turn`'s largest corrected angle and dead band, radians.
    upright : float
        Fraction of the model's standing pelvis height (its rest pose's) the latest pelvis must be at
        or above for any turn, in [0, 1] (0: no height gate).
    """

    def __init__(self, model: BodyModel, *, gain: float, speed_min: float, speed_full: float,
                 window_s: float, max_rad: float = np.pi, dead_rad: float = 0.0, upright: float = 0.0) -> None:
        if not 0.0 <= gain <= 1.0:
            raise ValueError(f"gain: expected a value in [0, 1], got {gain!r}")
        if not 0.0 <= speed_min < speed_full:
            raise ValueError(f"speed_min, speed_full: expected 0 <= speed_min < speed_full, got "
                             f"{speed_min!r}, {speed_full!r}")
        if not window_s > 0:
            raise ValueError(f"window_s: expected > 0, got {window_s!r}")
        if not 0.0 <= dead_rad < max_rad:
            raise ValueError(f"dead_rad: expected 0 <= dead_rad < max_rad, got {dead_rad!r}")
        if not 0.0 <= upright <= 1.0:
            raise ValueError(f"upright: expected a value in [0, 1], got {upright!r}")
        self.model = model
        self.gain, self.speed_min, self.speed_full, self.window_s = gain, speed_min, speed_full, window_s
        self.max_rad, self.dead_rad = float(max_rad), float(dead_rad)
        self.root_joint = list(model.joint_names).index("pelvis")
        rest = joint_centre_array(model, forward(model, model.zero()))
        #: the pelvis joint's height in the model's rest pose (metres): the standing height
        self.standing_z = float(rest[self.root_joint, 2])
        self.min_z = upright * self.standing_z
        self._track: deque = deque()
        self._z = np.inf

    def reset(self) -> None:
        """Forget the positions (a lost track: the next velocity starts afresh)."""
        self._track.clear()
        self._z = np.inf

    def velocity(self) -> np.ndarray:
        """Horizontal velocity (2,) m/s: least-squares slope over the window; zeros with under two
        positions or one timestamp."""
        if len(self._track) < 2:
            return np.zeros(2)
        t = np.array([s for s, _ in self._track])
        xy = np.array([p for _, p in self._track])
        t = t - t.mean()
        tt = float(t @ t)
        return (t @ (xy - xy.mean(axis=0))) / tt if tt > 0 else np.zeros(2)

    def add(self, t_s: float, point_xy, pelvis_z: float = np.inf) -> None:
        """Record a body point ``point_xy`` (2,) metres (the fitted pelvis joint, or the hull's centroid)
        at time ``t_s`` (seconds) and the fitted pelvis joint's height ``pelvis_z`` (metres; inf: not
        known, no height gate); drop positions older than the window."""
        self._track.append((float(t_s), np.asarray(point_xy, dtype=float).reshape(2).copy()))
        self._z = float(pelvis_z)
        while len(self._track) > 2 and self._track[-1][0] - self._track[1][0] >= self.window_s:
            self._track.popleft()

    def add_pose(self, t_s: float, joints: np.ndarray) -> None:
        """:meth:`add` the pelvis joint of fitted joint centres ``joints`` (n_joints, 3) metres."""
        self.add(t_s, joints[self.root_joint, :2], joints[self.root_joint, 2])

    def turn(self, params: np.ndarray) -> float:
        """Turn (radians about +z) this pose's pelvis should make toward the walking direction."""
        if self._z < self.min_z:
            return 0.0
        return walk_turn(pelvis_heading(self.model, params), self.velocity(), gain=self.gain,
                         speed_min=self.speed_min, speed_full=self.speed_full, max_rad=self.max_rad,
                         dead_rad=self.dead_rad)
