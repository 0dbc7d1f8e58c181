"""Centred-window smoothing of pose trajectories (offline: the frames after a frame are known).

A trajectory is ``params`` of shape ``(n, n_params)`` (``tracker.body.kinematics``: root translation in
metres, root rotation vector in radians, then joint angles in radians inside the model's limits), one row per
consecutive frame, cut into segments by ``breaks`` (a frame with ``breaks[k]`` True starts a new segment: a
missing pose, a re-initialisation, a mirror switch).  Frame k's window is the rows k − h … k + h of its own
segment, h = min(``half``, frames to the segment's start, frames to its end): it shrinks symmetrically at a
segment's ends, so a trajectory linear in time is kept and a segment's first and last frames are unchanged.
Neighbours are weighted by ``weights``, the pair k ± d by the lighter of the two (the frame itself by 1).

- ``smooth_params``: the window mean of the parameters.  Joint angles are averaged as numbers (a mean inside the
  box of limits stays inside it).  The root rotation is averaged as unit quaternions of one sign along the
  segment, written back as the rotation vector nearest the frame's own (no wrap at ±π).  The root turns about
  the model's origin (the floor under the pelvis), so it is averaged as the pelvis's position (``root_centre``)
  and the rotation, the translation recomputed from both (apart, they would swing the body on that lever).
- ``smooth_poses``: the pose of the model nearest the window mean of the joint centres (``fit_joints``, from
  ``smooth_params``' pose): bone lengths and joint limits hold.

Pure numpy, vectorised over frames and parameters (one pass per window offset); the joint fit is one small
solve per frame.
"""

from __future__ import annotations

import numpy as np

from tracker.body.kinematics import forward, joint_centre_array, point_jacobian, so3_exp
from tracker.body.model import ROOT_ROTATION, ROOT_TRANSLATION, BodyModel

__all__ = ["segment_halves", "window_mean", "smooth_params", "smooth_poses", "fit_joints", "root_centre",
           "rotvec_to_quat", "quat_to_rotvec", "nearest_rotvec"]


def root_centre(model: BodyModel) -> np.ndarray:
    """The point the root is averaged about: the pelvis joint in the zero pose (the root part's frame,
    metres), else the origin; shape (3,)."""
    if "pelvis" not in model.joint_names:
        return np.zeros(3)
    return joint_centre_array(model, forward(model, model.zero()))[model.joint_names.index("pelvis")]


def segment_halves(breaks: np.ndarray, half: int) -> np.ndarray:
    """Each frame's window half-width: ``half`` shrunk to the frames left to its segment's start and end.

    Parameters
    ----------
    breaks : ndarray of bool, shape (n,), True where a frame starts a new segment (frame 0 always does)
    half : int, ≥ 0

    Returns
    -------
    ndarray of int, shape (n,)
    """
    breaks = np.asarray(breaks, bool).copy()
    n = len(breaks)
    if n == 0:
        return np.zeros(0, int)
    breaks[0] = True
    idx = np.arange(n)
    start = np.maximum.accumulate(np.where(breaks, idx, 0))
    ends = np.append(breaks[1:], True)  # frame k ends a segment
    stop = np.minimum.accumulate(np.where(ends, idx, n - 1)[::-1])[::-1]
    return np.minimum(np.minimum(idx - start, stop - idx), int(half))


def rotvec_to_quat(r: np.ndarray) -> np.ndarray:
    """Rotation vectors (radians), shape (..., 3) -> unit quaternions (w, x, y, z), shape (..., 4)."""
    r = np.asarray(r, float)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    small = theta < 1e-9
    s = np.where(small, 0.5 - theta ** 2 / 48.0, np.sin(0.5 * theta) / np.where(small, 1.0, theta))
    return np.concatenate([np.cos(0.5 * theta), s * r], axis=-1)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z), shape (..., 4), any norm > 0 -> principal rotation vectors, shape (..., 3), |r| ≤ π."""
    q = np.asarray(q, float)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    v = q[..., 1:]
    sv = np.linalg.norm(v, axis=-1, keepdims=True)
    theta = 2.0 * np.arctan2(sv, q[..., :1])
    small = sv < 1e-12
    scale = np.where(small, 2.0 / np.where(q[..., :1] > 0, q[..., :1], 1.0), theta / np.where(small, 1.0, sv))
    return scale * v


def nearest_rotvec(r: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The rotation vectors equivalent to ``r`` (the same rotations) nearest to ``reference``, both shape (n, 3).

    A rotation by θ about unit axis a is also θ + 2πk about a; the k nearest the reference is taken.
    """
    r, reference = np.asarray(r, float), np.asarray(reference, float)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    ok = theta[:, 0] > 1e-9
    axis = np.where(ok[:, None], r / np.where(ok[:, None], theta, 1.0), 0.0)
    k0 = np.round((np.sum(reference * axis, axis=-1, keepdims=True) - theta) / (2 * np.pi))
    cands = np.stack([(theta + 2 * np.pi * (k0 + d)) * axis for d in (-1.0, 0.0, 1.0)])  # (3, n, 3)
    best = np.argmin(np.sum((cands - reference[None]) ** 2, axis=-1), axis=0)
    out = cands[best, np.arange(len(r))]
    return np.where(ok[:, None], out, r)


def window_mean(X: np.ndarray, halves: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Each row's weighted mean over the rows k − h_k … k + h_k (h_k = ``halves[k]``); row k itself weighs 1,
    the pair of rows k ± d each the lighter weight of the two (the window stays symmetric: no lag).

    Parameters
    ----------
    X : ndarray, shape (n, ...)
    halves : ndarray of int, shape (n,), ≥ 0 (``segment_halves``: never past a row's segment)
    weights : ndarray, shape (n,), optional, ≥ 0, each row's weight as a neighbour (None: all 1)

    Returns
    -------
    ndarray, shape of ``X``
    """
    X = np.asarray(X, float)
    n = len(X)
    h = np.asarray(halves, int)
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    idx = np.arange(n)
    acc, wsum = X.copy(), np.ones(n)
    shape = (n,) + (1,) * (X.ndim - 1)
    for d in range(1, int(h.max(initial=0)) + 1):
        inside = h >= d
        after, before = np.minimum(idx + d, n - 1), np.maximum(idx - d, 0)
        # the pair k ± d weighs the lighter of the two each: the window stays symmetric (no lag)
        wd = np.where(inside, np.minimum(w[after], w[before]), 0.0)
        for j in (after, before):
            acc += np.where(inside.reshape(shape), wd.reshape(shape) * X[j], 0.0)
            wsum += wd
    return acc / wsum.reshape(shape)


def smooth_params(model: BodyModel, params: np.ndarray, *, half: int, breaks: np.ndarray | None = None,
                  weights: np.ndarray | None = None) -> np.ndarray:
    """The centred-window mean of a parameter trajectory, per segment (module docstring).

    Parameters
    ----------
    model : BodyModel, whose parameters the rows are (its root rotation columns and joint limits)
    params : ndarray, shape (n, model.n_params), one row per consecutive frame
    half : int, ≥ 0, the window's half-width in frames (0: unchanged)
    breaks : ndarray of bool, shape (n,), optional, True where a frame starts a new segment
    weights : ndarray, shape (n,), optional, ≥ 0, each frame's weight as a neighbour (None: all 1)

    Returns
    -------
    ndarray, shape (n, model.n_params)
    """
    P = np.asarray(params, float)
    n = len(P)
    if P.ndim != 2 or P.shape[1] != model.n_params:
        raise ValueError(f"params: expected shape (n, {model.n_params}), got {P.shape}")
    if half < 0:
        raise ValueError(f"half: expected >= 0, got {half}")
    breaks = np.zeros(n, bool) if breaks is None else np.asarray(breaks, bool)
    w = np.ones(n) if weights is None else np.asarray(weights, float)
    if breaks.shape != (n,) or w.shape != (n,) or (w < 0).any():
        raise ValueError(f"breaks, weights: expected shape ({n},) (weights >= 0), got {breaks.shape}, {w.shape}")
    h = segment_halves(breaks, half)
    if n == 0 or not h.any():
        return P.copy()
    rot = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    other = np.flatnonzero(model.param_kind != ROOT_ROTATION)
    trans = np.flatnonzero(model.param_kind[other] == ROOT_TRANSLATION)  # columns of X
    X = P[:, other].copy()
    lever = len(rot) == 3 and len(trans) == 3
    if lever:  # the root's translation as the pelvis's position
        c = root_centre(model)
        X[:, trans] += so3_exp(P[:, rot]) @ c
    if len(rot):
        q = rotvec_to_quat(P[:, rot])
        flip = np.einsum("ij,ij->i", q[1:], q[:-1]) < 0
        q *= np.cumprod(np.where(np.append(False, flip), -1.0, 1.0))[:, None]  # one sign along each segment
        X = np.concatenate([X, q], axis=1)
    M = window_mean(X, h, w)
    out = P.copy()
    out[:, other] = np.clip(M[:, :len(other)], model.lower[other], model.upper[other])
    if len(rot):
        out[:, rot] = nearest_rotvec(quat_to_rotvec(M[:, len(other):]), P[:, rot])
    if lever:
        out[:, other[trans]] = M[:, trans] - so3_exp(out[:, rot]) @ c
    return np.where((h > 0)[:, None], out, P)


def fit_joints(model: BodyModel, params: np.ndarray, targets: np.ndarray, *, damping: float = 0.01,
               iterations: int = 5) -> np.ndarray:
    """Poses whose joint centres are nearest ``targets``, from ``params`` and held near them: per frame,
    Levenberg–Marquardt steps on ``|joints(Φ) − target|² + damping² |Φ − params|²``, each step projected onto
    the joint limits and kept only when it lowers that cost (so bone lengths and limits hold whatever the
    targets, and the result is never worse than the start by that cost).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n, model.n_params), the start and the prior
    targets : ndarray, shape (n, len(model.joint_names), 3), metres, world
    damping : float, > 0, metres per radian (per metre for the root translation)
    iterations : int, ≥ 1, steps tried per frame

    Returns
    -------
    ndarray, shape (n, model.n_params)
    """
    P = np.asarray(params, float)
    T = np.asarray(targets, float)
    n, m = P.shape
    out = P.copy()
    eye = np.eye(m)

    def cost(p, k):
        pose = forward(model, p)
        X = pose.to_world(model.joint_part, model.joint_point)
        r = (X - T[k]).ravel()
        return float(r @ r + damping ** 2 * np.sum((p - P[k]) ** 2)), pose, X, r

    for k in range(n):  # one small solve per frame
        p = P[k].copy()
        c, pose, X, r = cost(p, k)
        lam = 1e-3
        for _ in range(iterations):
            J = point_jacobian(model, pose, model.joint_part, X).reshape(-1, m)
            A = J.T @ J + damping ** 2 * eye
            g = J.T @ r + damping ** 2 * (p - P[k])
            q = np.clip(p - np.linalg.solve(A + lam * np.diag(np.diag(A)), g), model.lower, model.upper)
            c2, pose2, X2, r2 = cost(q, k)
            if c2 < c:
                p, c, pose, X, r, lam = q, c2, pose2, X2, r2, lam * 0.3
            else:
                lam *= 10.0
        out[k] = p
    return out


def smooth_poses(model: BodyModel, params: np.ndarray, joints: np.ndarray, *, half: int,
                 breaks: np.ndarray | None = None, weights: np.ndarray | None = None,
                 damping: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed poses: the window mean of the joint centres, reached by the model (``fit_joints``) from the
    window mean of the parameters (``smooth_params``), so bone lengths and joint limits hold.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n, model.n_params), one row per consecutive frame
    joints : ndarray, shape (n, len(model.joint_names), 3), the frames' joint centres (metres, world)
    half, breaks, weights : as ``smooth_params``
    damping : float, ``fit_joints``' pull towards the parameters' mean

    Returns
    -------
    params : ndarray, shape (n, model.n_params)
    joints : ndarray, shape (n, len(model.joint_names), 3); a frame whose window is itself alone unchanged
    """
    P, Jt = np.asarray(params, float), np.asarray(joints, float)
    breaks = np.zeros(len(P), bool) if breaks is None else breaks
    h = segment_halves(breaks, half)
    Q = smooth_params(model, P, half=half, breaks=breaks, weights=weights)
    moved = np.flatnonzero(h > 0)
    if len(moved) == 0:
        return P.copy(), Jt.copy()
    Q[moved] = fit_joints(model, Q[moved], window_mean(Jt, h, weights)[moved], damping=damping)
    J = Jt.copy()
    J[moved] = [joint_centre_array(model, forward(model, q)) for q in Q[moved]]
    return Q, J
