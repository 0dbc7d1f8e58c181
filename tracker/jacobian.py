"""The extremal-contour Jacobian dx/dΦ = J_I (A + B) J_H (IJCV 2008 §5), derived afresh.

A contour point of part p sits at ``Y = R X(θ, z) + t`` (part2world R, t) with z
fixed (``tracker.contours``) and θ a root of the tangency equation (contours.py)::

    f(θ; m) = a b (1 + k m3) - m · n(θ) = 0,   m = R^T (C - t),   n(θ) = (b cos θ, a sin θ, -a b k)

for the camera centre C (world).  When the part moves with the spatial screw
``(ω, v)`` (every point Y of the part moves as ``ω × Y + v``), the point moves

- rigidly, ``A (ω; v) = ω × Y + v``, ``A = [-[Y]×  I]`` (3×6): the rigid term;
- and slides along the surface, ``R X_θ dθ``, to stay on the contour generator:
  the camera seen from the part frame moves as ``dm = -R^T (ω × C + v)`` and
  ``∂f/∂m = -n``, so ``dθ = -(∂f/∂m · dm) / f_θ = -(R n) · (ω × C + v) / f_θ``
  with ``f_θ = -m · n_θ = b m1 sin θ - a m2 cos θ``.  Hence the sliding term::

      B = -(1 / f_θ) (R X_θ) [(C × R n)^T  (R n)^T]          (3×6, rank 1)

  (``(R n)^T [-[C]×  I] = [(C × R n)^T  (R n)^T]``).  ``X_θ`` lies in the tangent
  plane, which contains the line of sight, so ``J_I B`` runs along the image
  contour: it moves the matched sample along its ruling's image, never across it.

``J_H`` (6 × n_params) is the part's body Jacobian (``tracker.kinematics``): the
screws of the parameters moving it.  ``J_I`` (2×3) is
``Camera.project_with_jacobian`` (distortion included).  The product is formed
as ``(J_I (A + B)) @ screws``: one (2n, 6) @ (6, n_params) matrix product, then
masked by ``model.affects``; no (n, n_params, 3) temporary.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from capture.camera import Camera
from tracker.contours import Contours, camera_centres
from tracker.kinematics import Pose
from tracker.model import BodyModel

__all__ = ["contour_jacobian", "contour_point_jacobian", "contour_motion"]


def _select(contours: Contours, rows) -> np.ndarray:
    if rows is None:
        return np.arange(contours.n_points)
    rows = np.asarray(rows)
    if rows.dtype == bool:
        if rows.shape != (contours.n_points,):
            raise ValueError(f"rows: a boolean mask must have shape ({contours.n_points},), got {rows.shape}")
        return np.flatnonzero(rows)
    if rows.ndim != 1 or (rows.size and (rows.min() < 0 or rows.max() >= contours.n_points)):
        raise ValueError(f"rows: indices must be a 1-D array within [0, {contours.n_points})")
    return rows.astype(np.intp, copy=False)


def _check(model: BodyModel, cameras: Sequence[Camera], contours: Contours) -> None:
    if contours.n_parts != model.n_parts:
        raise ValueError(f"contours: computed for {contours.n_parts} parts, model {model.name!r} has {model.n_parts}")
    if contours.n_cams != len(cameras):
        raise ValueError(f"cameras: {len(cameras)} given, contours were computed for {contours.n_cams}")


def _terms(model, pose, centres, contours, r, sliding):
    """Per-point pieces: Y (n,3) and, for the sliding term, e = R X_θ / (-f_θ), nw = R n, C×nw."""
    part, th, z = contours.part[r], contours.theta[r], contours.z[r]
    Y = contours.points[r]
    if not sliding:
        return Y, None, None, None
    a, b, k = model.cones[part, 0], model.cones[part, 1], model.cones[part, 2]
    R, t = pose.rotation[part], pose.translation[part]
    C = centres[contours.cam[r]]
    cos, sin = np.cos(th), np.sin(th)
    m = np.einsum("nji,nj->ni", R, C - t)  # camera centre in the part frame
    f_theta = b * m[:, 0] * sin - a * m[:, 1] * cos
    # f_θ = 0 only where the two rulings merge (grazing view): no contour there
    f_theta = np.where(np.abs(f_theta) > 1e-300, f_theta, 1e-300)
    s = (1.0 + k * z) / -f_theta
    e = np.einsum("nij,nj->ni", R[:, :, :2], np.stack([-a * sin * s, b * cos * s], axis=1))
    nw = np.einsum("nij,nj->ni", R, np.stack([b * cos, a * sin, -a * b * k], axis=1))
    return Y, e, nw, np.cross(C, nw)


def contour_motion(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    contours: Contours,
    *,
    sliding: bool = True,
    rows=None,
) -> np.ndarray:
    """A + B per contour point: the point's velocity per unit screw of its part.

    Returns
    -------
    ndarray, shape (n, 3, 6)
        ``dY = (A + B) (ω; v)``, columns ω then v (world); n = N or len(rows).
    """
    _check(model, cameras, contours)
    r = _select(contours, rows)
    Y, e, nw, cxn = _terms(model, pose, camera_centres(cameras), contours, r, sliding)
    out = np.zeros((r.size, 3, 6))
    # A = [-[Y]x  I]
    out[:, 0, 1], out[:, 0, 2] = Y[:, 2], -Y[:, 1]
    out[:, 1, 0], out[:, 1, 2] = -Y[:, 2], Y[:, 0]
    out[:, 2, 0], out[:, 2, 1] = Y[:, 1], -Y[:, 0]
    out[:, 0, 3] = out[:, 1, 4] = out[:, 2, 5] = 1.0
    if sliding:
        out += e[:, :, None] * np.concatenate([cxn, nw], axis=1)[:, None, :]
    return out


def _screws(model: BodyModel, pose: Pose) -> np.ndarray:
    """All parameters' spatial screws, shape (6, n_params) (J_H before the per-part mask)."""
    return np.concatenate([pose.screw_w, pose.screw_v], axis=1).T


def contour_point_jacobian(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    contours: Contours,
    *,
    sliding: bool = True,
    rows=None,
) -> np.ndarray:
    """dY/dΦ = (A + B) J_H of the contour points in the world, shape (n, 3, n_params)."""
    r = _select(contours, rows)
    V = contour_motion(model, pose, cameras, contours, sliding=sliding, rows=r)
    J = (V.reshape(-1, 6) @ _screws(model, pose)).reshape(r.size, 3, model.n_params)
    return J * model.affects[contours.part[r]][:, None, :]


def contour_jacobian(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    contours: Contours,
    *,
    sliding: bool = True,
    rows=None,
) -> np.ndarray:
    """Image Jacobian of the contour points, dx/dΦ = J_I (A + B) J_H.

    Parameters
    ----------
    model, pose : the body and its pose (``tracker.kinematics.forward``)
    cameras : sequence of Camera, the ones ``contours`` was computed for
    contours : Contours
    sliding : bool
        Include the sliding term B (False: the rigid-point approximation).
    rows : ndarray of int (n,) or bool (N,), optional
        Compute only these points (e.g. ``contours.visible``).

    Returns
    -------
    ndarray, shape (n, 2, n_params)
        Pixels per unit parameter (radians, metres); n = N or len(rows).
    """
    _check(model, cameras, contours)
    r = _select(contours, rows)
    Y, e, nw, cxn = _terms(model, pose, camera_centres(cameras), contours, r, sliding)
    JI = np.empty((r.size, 2, 3))
    cam = contours.cam[r]
    with np.errstate(all="ignore"):  # invalid rows (behind a camera) give junk, as their uv does
        for c, camera in enumerate(cameras):
            sel = cam == c
            if sel.any():
                JI[sel] = camera.project_with_jacobian(Y[sel])[1]
    # J_I A: row j of J_I gives (Y × j, j);  J_I B: (J_I e) ⊗ (C × nw, nw)
    M = np.empty((r.size, 2, 6))
    M[:, :, :3] = np.cross(Y[:, None, :], JI)
    M[:, :, 3:] = JI
    if sliding:
        JIe = np.einsum("nij,nj->ni", JI, e)
        M += JIe[:, :, None] * np.concatenate([cxn, nw], axis=1)[:, None, :]
    J = (M.reshape(-1, 6) @ _screws(model, pose)).reshape(r.size, 2, model.n_params)
    return J * model.affects[contours.part[r]][:, None, :]
