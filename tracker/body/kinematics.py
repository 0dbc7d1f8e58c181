"""Zero-reference forward kinematics and the body Jacobian J_H (IJCV 2008 §3–4).

Parameters Φ (shape ``(n_params,)``) are the free root motion Ψ — translation
``t`` (metres) and rotation vector ``r`` (radians, world frame) — followed by
the joint angles λ (radians).  Every part's pose is

    H_p(Φ) = D(Ψ) · Π_{joints j on the chain to p} Q_j(λ_j) · H_p(0)

with ``D(Ψ) = [exp([r]×) | t]`` and ``Q_j = U_j J(λ_j) U_j⁻¹`` a rotation about
a fixed axis through the joint centre.  We evaluate it recursively
(``part2world = parent2world · Trans(offset) · Rot(rest) · Rot(λ)``), which is
the same product.

**Body Jacobian.**  For a world point X rigidly attached to part p,

    dX/dΦ_k = affects[p, k] · (ω_k × X + v_k)

where ``(ω_k, v_k)`` is the spatial kinematic screw of parameter k (IJCV
eq. 47, ``Ĥ = [[ω]× v; 0 0]``, so ``Ẋ = ω × X + v``):

- root translation: ``ω = 0``, ``v = e_k``;
- root rotation: ``ω = J_l(r) e_k`` (left Jacobian of SO(3), since
  ``d exp([r]×) · exp(-[r]×) = [J_l(r) dr]×``) and ``v = t × ω``;
- joint angle about unit axis ``a`` (part frame) through the joint centre c:
  ``ω = R_before a`` (the axis carried by everything before this DOF) and
  ``v = c × ω``.

``body_jacobian`` returns these screws stacked per part:
``J_H[p] = [ω; v] * affects[p]`` with shape ``(n_parts, 6, n_params)``.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from tracker.kernels import forward_kinematics
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel

__all__ = ["Pose", "forward", "parameter_screws", "body_jacobian", "point_jacobian", "joint_centres", "so3_exp", "so3_left_jacobian"]


def _skew(w: np.ndarray) -> np.ndarray:
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    z = np.zeros(w.shape[:-1])
    return np.stack(
        [
            np.stack([z, -w[..., 2], w[..., 1]], -1),
            np.stack([w[..., 2], z, -w[..., 0]], -1),
            np.stack([-w[..., 1], w[..., 0], z], -1),
        ],
        -2,
    )


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation vectors to matrices.

    Parameters
    ----------
    w : ndarray, shape (..., 3)
        Rotation vectors, radians.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = _skew(w)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    A = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    B = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + A * K + B * (K @ K)


def so3_left_jacobian(w: np.ndarray) -> np.ndarray:
    """Left Jacobian of SO(3): ``[J_l(w) dw]× = d exp(w) exp(w)ᵀ``.

    Parameters
    ----------
    w : ndarray, shape (3,)
        Rotation vector, radians.

    Returns
    -------
    ndarray, shape (3, 3)
    """
    w = np.asarray(w, dtype=float)
    theta = float(np.linalg.norm(w))
    K = _skew(w)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * K + (K @ K) / 6.0
    return (
        np.eye(3)
        + (1.0 - np.cos(theta)) / theta**2 * K
        + (theta - np.sin(theta)) / theta**3 * (K @ K)
    )


@dataclass(frozen=True, eq=False)
class Pose:
    """A posed body.

    Attributes
    ----------
    params : ndarray, shape (n_params,)
    rotation : ndarray, shape (n_parts, 3, 3)
        part2world rotations.
    translation : ndarray, shape (n_parts, 3)
        part2world translations (part origins = joint centres), metres.
    screw_w, screw_v : ndarray, shape (n_params, 3)
        Spatial kinematic screw (ω, v) of each parameter (see module doc).
    """

    params: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    screw_w: np.ndarray
    screw_v: np.ndarray

    def part2world(self) -> np.ndarray:
        """Homogeneous part2world transforms.

        Returns
        -------
        ndarray, shape (n_parts, 4, 4)
        """
        n = self.rotation.shape[0]
        T = np.zeros((n, 4, 4))
        T[:, :3, :3] = self.rotation
        T[:, :3, 3] = self.translation
        T[:, 3, 3] = 1.0
        return T

    def to_world(self, part: np.ndarray, points_part: np.ndarray) -> np.ndarray:
        """Points given in part frames, in world coordinates.

        Parameters
        ----------
        part : ndarray of int, shape (n,)
        points_part : ndarray, shape (n, 3)
            Metres, in the frame of ``part``.

        Returns
        -------
        ndarray, shape (n, 3)
        """
        return np.einsum("nij,nj->ni", self.rotation[part], points_part) + self.translation[part]


_PLANS: "weakref.WeakKeyDictionary[BodyModel, tuple]" = weakref.WeakKeyDictionary()


def _plan(model: BodyModel) -> tuple:
    """Per-model constants of ``forward`` (cached), the arguments of
    ``tracker.kernels.forward_kinematics`` after ``params``: joint axes, parents, each part's joint
    parameters (``dof_idx[dof_ptr[p]:dof_ptr[p + 1]]``), rest rotations, offsets, and the indices of
    the root-translation and root-rotation parameters."""
    plan = _PLANS.get(model)
    if plan is None:
        kind = model.param_kind
        dofs = [np.flatnonzero((model.param_part == p) & (kind == JOINT_ROTATION)) for p in range(model.n_parts)]
        ptr = np.concatenate([[0], np.cumsum([len(d) for d in dofs])]).astype(np.intp)
        ti, ri = np.flatnonzero(kind == ROOT_TRANSLATION), np.flatnonzero(kind == ROOT_ROTATION)
        if len(ti) != 3 or len(ri) != 3 or np.any(model.parent[:1] >= 0):
            raise ValueError(f"model {model.name!r}: forward expects part 0 as the root with 3 translation "
                             "and 3 rotation parameters")
        plan = tuple(np.ascontiguousarray(a) for a in (
            np.asarray(model.param_axis, dtype=float), np.asarray(model.parent, dtype=np.intp), ptr,
            np.concatenate(dofs).astype(np.intp), np.asarray(model.rest_rotation, dtype=float),
            np.asarray(model.offset, dtype=float), ti.astype(np.intp), ri.astype(np.intp)))
        _PLANS[model] = plan
    return plan


def forward(model: BodyModel, params: np.ndarray) -> Pose:
    """Forward kinematics of every part and the parameters' kinematic screws.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)

    Returns
    -------
    Pose
    """
    params = np.asarray(params, dtype=float)
    if params.shape != (model.n_params,):
        raise ValueError(f"params must have shape ({model.n_params},) for model {model.name!r}, got {params.shape}")
    # part2world = parent2world · Trans(offset) · Rot(rest) · Π Rot(axis, λ), parents first; the
    # screws as in the module docstring (one compiled loop: tracker.kernels.forward_kinematics)
    R, t, w, v = forward_kinematics(params, *_plan(model))
    return Pose(params, R, t, w, v)


def parameter_screws(pose: Pose) -> np.ndarray:
    """Every parameter's spatial screw (ω; v) as columns: J_H before the per-part mask.

    Parameters
    ----------
    pose : Pose

    Returns
    -------
    ndarray, shape (6, n_params)
    """
    return np.concatenate([pose.screw_w, pose.screw_v], axis=1).T


def body_jacobian(model: BodyModel, pose: Pose) -> np.ndarray:
    """J_H for every part: the kinematic screws (ω; v) of the parameters that move it.

    Parameters
    ----------
    model : BodyModel
    pose : Pose

    Returns
    -------
    ndarray, shape (n_parts, 6, n_params)
    """
    return parameter_screws(pose)[None, :, :] * model.affects[:, None, :]


def point_jacobian(model: BodyModel, pose: Pose, part: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """dX/dΦ for world points rigidly attached to parts.

    Parameters
    ----------
    part : ndarray of int, shape (n,)
    points_world : ndarray, shape (n, 3)

    Returns
    -------
    ndarray, shape (n, 3, n_params)
    """
    X = np.asarray(points_world, dtype=float)
    # ω × X + v  for every (point, parameter): (n, n_params, 3)
    vel = np.cross(pose.screw_w[None, :, :], X[:, None, :]) + pose.screw_v[None, :, :]
    vel *= model.affects[part][:, :, None]
    return vel.transpose(0, 2, 1)


def joint_centres(model: BodyModel, pose: Pose) -> dict[str, np.ndarray]:
    """Named joint centres in world coordinates.

    Parameters
    ----------
    model : BodyModel
    pose : Pose

    Returns
    -------
    dict str -> ndarray, shape (3,)
        Metres.
    """
    pts = pose.to_world(model.joint_part, model.joint_point)
    return {name: pts[i] for i, name in enumerate(model.joint_names)}


def joint_centre_array(model: BodyModel, pose: Pose) -> np.ndarray:
    """Joint centres in ``model.joint_names`` order.

    Parameters
    ----------
    model : BodyModel
    pose : Pose

    Returns
    -------
    ndarray, shape (n_joints, 3)
        Metres, world.
    """
    return pose.to_world(model.joint_part, model.joint_point)
