"""Pose from goal points: the root by least squares, the limbs by inverse kinematics (BMVC'04 §4.2).

Goals are world points that given points on the body (``part`` index and ``point`` in its frame)
should reach — here the blobs' maximisation means for their attachment points.

- :func:`fit_root` moves the whole body rigidly (root translation and rotation only) to the goals
  of the trunk, by weighted least squares (Kabsch), constrained by the previous orientation: the
  cross-covariance gets ``orientation_weight · I`` added, i.e. pseudo-correspondences of the body's
  own axes that pull the rotation towards no change, and a rotation above ``max_turn_rad`` is
  refused (no sudden back/front flips).
- :func:`ccd` is cyclic coordinate descent: one joint angle at a time, from the end effectors back
  to the root (reverse parameter order: a part's parameters come after its parent's), each set in
  closed form to the angle about its axis that best brings the points it moves onto their goals,
  times an ``attenuation`` factor, regularised by ``damping`` (m²) towards its current value and
  clipped to the model's joint limits.  Within a sweep no forward kinematics is needed: a
  parameter's axis and centre depend only on parameters before it, which the sweep has not yet
  changed, and the moved points are rotated in place.
- :func:`damped_least_squares` is the alternative: Gauss–Newton steps on all free joint angles at
  once with the analytic point Jacobian (``tracker.body.kinematics.point_jacobian``), Levenberg damping,
  clipped to the limits.
- :func:`floor_contact` keeps the body out of the floor and puts it on the floor when its lowest
  point is within ``snap_m`` above it (the paper makes one part touch the floor; a hop leaves it).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.body.kinematics import forward, point_jacobian, so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.imaging.render import body_points

__all__ = ["fit_root", "ccd", "damped_least_squares", "floor_contact"]

_EYE = np.eye(3)


def _check(model: BodyModel, params, part, point, goals, weights):
    params = np.asarray(params, dtype=float)
    if params.shape != (model.n_params,):
        raise ValueError(f"params: expected shape ({model.n_params},), got {params.shape}")
    part = np.asarray(part, dtype=int)
    point = np.asarray(point, dtype=float).reshape(-1, 3)
    goals = np.asarray(goals, dtype=float).reshape(-1, 3)
    weights = np.ones(len(part)) if weights is None else np.asarray(weights, dtype=float)
    if not (len(part) == len(point) == len(goals) == len(weights)):
        raise ValueError("part, point, goals, weights: expected the same length")
    return params, part, point, goals, weights


def fit_root(model: BodyModel, params, part, point, goals, weights=None, *, orientation_weight: float = 0.0,
             max_turn_rad: float = np.radians(60.0)) -> np.ndarray:
    """Root translation and rotation moving body points onto goals (module docstring); returns params.

    ``part`` (m,), ``point`` (m, 3) part frame, ``goals`` (m, 3) world, ``weights`` (m,);
    ``orientation_weight`` in m² (summed weight × squared lever arm of a pseudo-correspondence).
    """
    params, part, point, goals, w = _check(model, params, part, point, goals, weights)
    if w.sum() <= 0:
        return params
    X = forward(model, params).to_world(part, point)
    ws = w / w.sum()
    xc, gc = ws @ X, ws @ goals
    H = ((X - xc) * ws[:, None]).T @ (goals - gc) + orientation_weight / w.sum() * np.eye(3)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    angle = np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0))
    if angle > max_turn_rad:
        R = np.eye(3)
    t = gc - R @ xc
    out = params.copy()
    ti = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    ri = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    out[ri] = Rotation.from_matrix(R @ so3_exp(params[ri])).as_rotvec()
    out[ti] = R @ params[ti] + t
    return out


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix (3, 3) by ``angle`` about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return _EYE + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def ccd(model: BodyModel, params, part, point, goals, weights=None, *, free=None, sweeps: int = 3,
        attenuation: float = 1.0, damping: float = 1e-4) -> np.ndarray:
    """Cyclic coordinate descent on the joint angles (module docstring); returns params within limits.

    ``free`` (n_params,) bool: joint angles it may change (default every joint angle); ``damping``
    in m² (per summed weight) pulls each angle towards its value at the start of the step.

    For the angle ``t`` about unit axis ``a`` through ``c``, with ``r = X − c`` and ``q = G − c``,
    ``Σ w |Rot(a, t) r − q|²`` is smallest at ``t = atan2(Σ w a·(r × q), Σ w (r·q − (r·a)(q·a)))``
    (the components along ``a`` play no part); the damping adds to the second sum.
    """
    params, part, point, goals, w = _check(model, params, part, point, goals, weights)
    free = (model.param_kind == JOINT_ROTATION) if free is None else np.asarray(free, bool) & (
        model.param_kind == JOINT_ROTATION)
    moved = model.affects[part] & (w > 0)[:, None]  # (m, n_params)
    order = [(int(k), np.flatnonzero(moved[:, k])) for k in np.flatnonzero(free)[::-1]]
    order = [(k, idx) for k, idx in order if idx.size]
    out = model.clamp(params)
    for _ in range(int(sweeps)):
        pose = forward(model, out)
        X = pose.to_world(part, point)
        for k, idx in order:
            axis = pose.screw_w[k]
            centre = pose.translation[model.param_part[k]]
            r = X[idx] - centre
            q = goals[idx] - centre
            ww = w[idx]
            rxq = np.column_stack([r[:, 1] * q[:, 2] - r[:, 2] * q[:, 1], r[:, 2] * q[:, 0] - r[:, 0] * q[:, 2],
                                   r[:, 0] * q[:, 1] - r[:, 1] * q[:, 0]])
            sin_t = ww @ (rxq @ axis)
            cos_t = ww @ ((r * q).sum(1) - (r @ axis) * (q @ axis)) + damping * ww.sum()
            if abs(sin_t) + abs(cos_t) < 1e-12:
                continue
            new = min(max(out[k] + attenuation * np.arctan2(sin_t, cos_t), model.lower[k]), model.upper[k])
            step = new - out[k]
            if step == 0.0:
                continue
            out[k] = new
            X[idx] = centre + r @ _rotation(axis, step).T
    return out


def damped_least_squares(model: BodyModel, params, part, point, goals, weights=None, *, free=None,
                         iterations: int = 3, damping: float = 1e-3, root: bool = False,
                         penalty=None, moves=None) -> np.ndarray:
    """Damped Gauss–Newton on the free joint angles (module docstring); returns params within limits.

    ``root``: the root's translation and rotation are free too (every goal then pulls the whole body,
    e.g. the legs' goals lower the trunk into a crouch).  ``penalty``: optional extra residuals, an
    object whose ``residuals(model, params, jacobian=, pose=)`` gives ``(r (k,), J (k, n_params) or None)``
    (``tracker.fitting.props.PropPenalty``), minimised with the goals (``r`` in the goals' units,
    metres × √weight); a step that raises the cost is then halved (at most 5 times, else the pose stays).
    ``moves`` (m, n_params) bool: which parameters goal ``i`` may pull (its other Jacobian columns are
    zeroed, e.g. arm goals that must not turn the trunk); default every parameter."""
    params, part, point, goals, w = _check(model, params, part, point, goals, weights)
    kinds = (JOINT_ROTATION, ROOT_TRANSLATION, ROOT_ROTATION) if root else (JOINT_ROTATION,)
    movable = np.isin(model.param_kind, kinds)
    free = movable if free is None else (np.asarray(free, bool) | (movable & (model.param_kind != JOINT_ROTATION))) & movable
    idx = np.flatnonzero(free)
    out = model.clamp(params)
    sw = np.sqrt(w)[:, None]
    if moves is not None:
        moves = np.asarray(moves, bool)
        if moves.shape != (len(part), model.n_params):
            raise ValueError(f"moves: expected shape ({len(part)}, {model.n_params}), got {moves.shape}")
        moves = moves[:, None, idx]
    for _ in range(int(iterations)):
        pose = forward(model, out)
        X = pose.to_world(part, point)
        J = point_jacobian(model, pose, part, X)[:, :, idx]  # (m, 3, f)
        if moves is not None:
            J = J * moves
        Jw = (J * sw[:, :, None]).reshape(-1, len(idx))
        r = ((goals - X) * sw).ravel()
        A = Jw.T @ Jw
        b = Jw.T @ r
        rp = None
        if penalty is not None:
            rp, Jp = penalty.residuals(model, out, jacobian=True, pose=pose)
            Jp = Jp[:, idx]
            A += Jp.T @ Jp
            b -= Jp.T @ rp
        A[np.diag_indices_from(A)] += damping * max(w.sum(), 1e-9)
        step = np.linalg.solve(A, b)
        if rp is None:
            out[idx] = np.clip(out[idx] + step, model.lower[idx], model.upper[idx])
            continue
        cost = r @ r + rp @ rp
        for _ in range(_MAX_HALVINGS):  # the limit is a hinge: a long step may jump into a box
            trial = out.copy()
            trial[idx] = np.clip(out[idx] + step, model.lower[idx], model.upper[idx])
            if _cost(model, trial, part, point, goals, sw, penalty) <= cost:
                out = trial
                break
            step = 0.5 * step
    return out


_MAX_HALVINGS = 5


def _cost(model: BodyModel, params, part, point, goals, sw, penalty) -> float:
    """The damped least squares' cost at ``params``: weighted squared goal distances plus the penalty's."""
    pose = forward(model, params)
    r = (goals - pose.to_world(part, point)) * sw
    rp, _ = penalty.residuals(model, params, pose=pose)
    return float(np.sum(r * r) + rp @ rp)


def floor_contact(model: BodyModel, params, *, floor_z: float = 0.0, snap_m: float = 0.02) -> np.ndarray:
    """Raise the body out of the floor, or lower it onto the floor when its lowest surface point is
    less than ``snap_m`` above it; returns params (only the root height changes)."""
    params = np.asarray(params, dtype=float).copy()
    low = float(body_points(model, forward(model, params), n_theta=8, n_z=2)[..., 2].min())
    gap = low - floor_z
    if gap < snap_m:
        params[np.flatnonzero(model.param_kind == ROOT_TRANSLATION)[2]] -= gap
    return params
