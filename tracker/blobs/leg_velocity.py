"""Leg velocity carried into the next frame's start: the legs keep their gait phase.

When the legs cross, the swinging leg's voxels pass next to the standing leg's and a start at the
last pose leaves both legs at the crossing, where the EM can hand either leg's voxels to either
blob chain.  Starting the legs where their own motion takes them (each leg's joint angles moved on
by their mean rate over the last fitted frames) puts each leg's blobs on its side of the crossing.

:class:`LegVelocity` keeps the last ``frames`` fitted poses (whether or not they passed the ok
gate: a hand outside the hull says nothing against the legs) and moves the legs' joint-rotation
parameters of a start pose by ``gain`` × their mean change per frame over that history, times a
weight of the pelvis's horizontal speed (the tracker's: ``walk_heading.speed_weight``, so a body
crouching or waving in place keeps its start: the prior is one of gait).

Two restrictions keep the rate to the gait's swing (``flexion_only``, ``antiphase``): only the
thighs' and shanks' flexions are carried (a rate of twist or abduction between two fits is mostly
the fits' noise about poorly seen axes), and only while the two thighs' flexion rates have opposite
signs (one leg swinging forward while the other goes back, as through a crossing); both thighs
moving the same way is no stride, and is not carried.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from tracker.body.model import JOINT_ROTATION, BodyModel

__all__ = ["LegVelocity", "leg_params", "thigh_flexions"]

_LEG_PARTS = ("thigh", "shank", "foot")


def leg_params(model: BodyModel) -> np.ndarray:
    """Which parameters are the legs' joint rotations (thighs, shanks, feet); (n_params,) bool."""
    legs = np.array([any(p.endswith(s) for s in _LEG_PARTS) for p in model.part_names])
    return (model.param_kind == JOINT_ROTATION) & legs[model.param_part]


def thigh_flexions(model: BodyModel) -> tuple[int, int]:
    """Indices of the left and right thighs' flexion parameters."""
    return model.param_index("left_thigh.flexion"), model.param_index("right_thigh.flexion")


class LegVelocity:
    """Per-frame rate of the legs' joint angles over the last fits (module docstring).

    Parameters
    ----------
    model : BodyModel
    gain : float >= 0, fraction of the mean rate added to the start (0: none)
    frames : int >= 2, fitted poses the rate is measured over
    flexion_only : carry only the legs' flexion parameters (module docstring)
    antiphase : carry nothing unless the thighs' flexion rates have opposite signs
    """

    def __init__(self, model: BodyModel, *, gain: float = 1.0, frames: int = 3, flexion_only: bool = True,
                 antiphase: bool = True) -> None:
        if not (gain >= 0 and int(frames) >= 2):
            raise ValueError(f"LegVelocity: need gain >= 0 and frames >= 2, got {gain!r}, {frames!r}")
        self.model = model
        self.gain = float(gain)
        self.legs = leg_params(model)
        if flexion_only:
            self.legs &= np.array([n.endswith(".flexion") for n in model.param_names])
        self.antiphase = bool(antiphase)
        self._thighs = thigh_flexions(model)
        self._poses: deque = deque(maxlen=int(frames))

    def reset(self) -> None:
        """Forget the history (a lost frame)."""
        self._poses.clear()

    def add(self, params: np.ndarray) -> None:
        """Record a fitted pose (n_params,)."""
        self._poses.append(np.asarray(params, float).copy())

    def rate(self) -> np.ndarray:
        """Mean change per frame of the carried parameters (0 elsewhere, with too short a history, or
        with ``antiphase`` and the thighs' flexion rates not of opposite signs); (n_params,) rad/frame."""
        out = np.zeros(self.model.n_params)
        if len(self._poses) < 2:
            return out
        out[self.legs] = (self._poses[-1][self.legs] - self._poses[0][self.legs]) / (len(self._poses) - 1)
        left, right = self._thighs
        if self.antiphase and not out[left] * out[right] < 0:
            out[:] = 0.0
        return out

    def start(self, params: np.ndarray, weight: float = 1.0) -> np.ndarray:
        """``params`` (n_params,) with the legs moved on by ``weight`` × ``gain`` × :meth:`rate`, within the
        limits (``weight`` in [0, 1]: how much the body walks, ``walk_heading.speed_weight``)."""
        return self.model.clamp(np.asarray(params, float) + weight * self.gain * self.rate())
