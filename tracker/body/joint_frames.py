"""Bone rotations of the body model relative to its T-pose, in a chosen output axis frame.

One implementation for every consumer that animates a skeleton from pose parameters: the BVH export
and the VMC stream.  The model's reference pose (all parameters 0) is a T-pose facing +X
(``tracker/models/*.toml``).  For part p with part2world rotation ``W_p`` and reference rotation
``W⁰_p``, the *world bone rotation* is ``D_p = W_p · W⁰_pᵀ``: the rotation that carries the bone from
the T-pose to the pose.  A skeleton whose bones at rest are the T-pose with world-aligned frames
(BVH with zero channels, a Unity humanoid avatar) is animated by the parent-relative rotations
``L_p = D_parentᵀ · D_p`` (``L_root = D_root``), with rest offsets ``W⁰_parent · offset_p`` (the T-pose
joint-to-joint vectors in world axes), which places every joint centre exactly where the model does.

Output axes: a 3×3 orthogonal matrix ``A`` maps tracker world coordinates (metres, right-handed, Z up)
to the output's; rotations become ``A · D · Aᵀ`` (a proper rotation even when ``det A = −1``, as for
Unity's left-handed frame), positions ``A · x``.  Pure numpy, no I/O.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

__all__ = ["AXES_Z_UP", "AXES_Y_UP", "AXES_UNITY", "axes_for", "JointFrames", "part_frames", "joint_frames"]

AXES_Z_UP = np.eye(3)
"""Tracker world as is: right-handed, Z up."""
AXES_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Right-handed Y up: ``(x, y, z) -> (x, z, -y)``, a −90° rotation about X (BVH, OpenSim)."""
AXES_UNITY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""Unity, left-handed Y up: ``(x, y, z) -> (-y, z, x)``; the T-pose (facing +X, left +Y) faces Unity's +Z
with its left hand at −X, as a Unity humanoid does (det = −1)."""


def axes_for(up: str) -> np.ndarray:
    """``"z"`` -> :data:`AXES_Z_UP`, ``"y"`` -> :data:`AXES_Y_UP` (ValueError otherwise)."""
    key = str(up).lower()
    if key == "z":
        return AXES_Z_UP
    if key == "y":
        return AXES_Y_UP
    raise ValueError(f"up axis must be 'z' or 'y', got {up!r}")


@dataclass(frozen=True)
class JointFrames:
    """Bone motion in output axes.

    Attributes
    ----------
    root_position : ndarray, shape (n, 3)
        Root part origin per frame, metres.
    world : ndarray, shape (n, n_parts, 3, 3)
        World bone rotations ``A D_p Aᵀ`` (identity at the T-pose).
    local : ndarray, shape (n, n_parts, 3, 3)
        Parent-relative bone rotations (the root's equals its world rotation).
    rest_offset : ndarray, shape (n_parts, 3)
        Part origin minus parent origin at the T-pose, metres (the root: its origin at the T-pose).
    end_site : ndarray, shape (n_parts, 3)
        Far end of the part's cone minus its origin at the T-pose, metres.
    """

    root_position: np.ndarray
    world: np.ndarray
    local: np.ndarray
    rest_offset: np.ndarray
    end_site: np.ndarray


def part_frames(model, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """part2world rotations (n, n_parts, 3, 3) and translations (n, n_parts, 3) for params (n, n_params)."""
    from tracker.body.kinematics import forward

    params = np.atleast_2d(np.asarray(params, dtype=float))
    n = params.shape[0]
    R = np.empty((n, model.n_parts, 3, 3))
    t = np.empty((n, model.n_parts, 3))
    for f in range(n):  # one forward-kinematics call per frame (vectorised over parts inside)
        pose = forward(model, params[f])
        R[f], t[f] = pose.rotation, pose.translation
    return R, t


_REST: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _rest(model) -> tuple[np.ndarray, np.ndarray]:
    """part2world rotations (n_parts, 3, 3) and translations (n_parts, 3) at the T-pose (cached per model)."""
    rest = _REST.get(model)
    if rest is None:
        R0, t0 = part_frames(model, model.zero())
        rest = _REST[model] = (R0[0], t0[0])
    return rest


def joint_frames(model, params: np.ndarray, axes: np.ndarray = AXES_Z_UP) -> JointFrames:
    """T-pose-relative bone rotations of ``params`` (n, n_params) in output ``axes`` (3, 3); see the module doc."""
    A = np.asarray(axes, dtype=float)
    if A.shape != (3, 3) or not np.allclose(A @ A.T, np.eye(3), atol=1e-9):
        raise ValueError("axes must be an orthogonal 3x3 matrix")
    R, t = part_frames(model, params)
    R0, t0 = _rest(model)
    D = R @ np.swapaxes(R0, -1, -2)[None]  # (n, parts, 3, 3)
    Dw = A[None, None] @ D @ A.T[None, None]
    local = Dw.copy()
    child = np.flatnonzero(model.parent >= 0)
    local[:, child] = np.swapaxes(Dw[:, model.parent[child]], -1, -2) @ Dw[:, child]
    rest = t0.copy()
    rest[child] = t0[child] - t0[model.parent[child]]
    tip = np.zeros((model.n_parts, 3))
    tip[:, 2] = np.asarray(model.cones)[:, 4]
    end = np.einsum("pij,pj->pi", R0, tip)
    return JointFrames(root_position=t[:, 0] @ A.T, world=Dw, local=local,
                       rest_offset=rest @ A.T, end_site=end @ A.T)
