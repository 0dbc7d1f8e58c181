"""The extremal-contour Jacobian dx/dΦ = J_I (A + B) J_H (IJCV 2008 §5), derived afresh.

A contour point of part p sits at ``Y = R X(θ, z) + t`` (part2world R, t) with z
fixed (``tracker.imaging.contours``) and θ a root of the tangency equation (contours.py)::

    f(θ; m) = a b (1 + k m3) - m · n(θ) = 0,   m = R^T (C - t),   n(θ) = (b cos θ, a sin θ, -a b k)

for the camera centre C (world).  When the part moves with the spatial screw
``(ω, v)`` (every point Y of the part moves as ``ω × Y + v``), the point moves

- rigidly, ``A (ω; v) = ω × Y + v``, ``A = [-[Y]×  I]`` (3×6): the rigid term;
- and slides along the surface, ``R X_θ dθ``, to stay on the contour generator:
  the camera seen from the part frame moves as ``dm = -R^T (ω × C + v)`` and
  ``∂f/∂m = -n``, so ``dθ = -(∂f/∂m · dm) / f_θ = -(R n) · (ω × C + v) / f_θ``
  with ``f_θ = -m · n_θ = b m1 sin θ - a m2 cos θ``.  Hence the sliding term::

      B = -(1 / f_θ) (R X_θ) [(C × R n)^T  (R n)^T]          (3×6, rank 1)

  (``(R n)^T [-[C]×  I] = [(C × R n)^T  (R n)^T]``); B = 0 on rows without a real
  ruling (``contours.valid`` False there anyway).  ``X_θ`` lies in the tangent
  plane, which contains the line of sight, so ``J_I B`` runs along the image
  contour: it moves the matched sample along its ruling's image, never across it.

Against the paper (IJCV 2008 eqs. 24, 29–31): its screw is taken about the part origin
(``V = ṫ``, ``A = [[t - X]× I]``), ours about the world origin (``v = ṫ - ω × t``,
``A = [-[X]× I]``; the paper's "equivalent" ``A = [[X]× I]`` has the wrong sign).  Its
``θ̇ = (R n)^T [[C - t]× - I] (ω; V) / ((X + R^T (t - C))^T n_θ)`` is ours with ``X · n_θ = 0``:
the denominator is ``f_θ`` and the numerator ``-(R n) · (ω × (C - t) + V)``.

``J_H`` (6 × n_params) is the part's body Jacobian (``tracker.body.kinematics``): the
screws of the parameters moving it.  ``J_I`` (2×3) is
``Camera.project_with_jacobian`` (distortion included).  The product is formed
as ``(J_I (A + B)) @ screws``: one (2n, 6) @ (6, n_params) matrix product, then
masked by ``model.affects``; no (n, n_params, 3) temporary.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from capture.camera import Camera, project_many_with_jacobian
from tracker.imaging.contours import Contours, camera_centres
from tracker.body.kinematics import Pose
from tracker.body.model import BodyModel

__all__ = ["contour_jacobian", "contour_image_motion", "apply_screws", "contour_point_jacobian", "contour_motion"]


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


def _check(model: BodyModel, pose: Pose, cameras: Sequence[Camera], contours: Contours) -> None:
    if contours.n_parts != model.n_parts:
        raise ValueError(f"contours: computed for {contours.n_parts} parts, model {model.name!r} has {model.n_parts}")
    if pose.rotation.shape[0] != model.n_parts or pose.screw_w.shape[0] != model.n_params:
        raise ValueError(f"pose: computed for another model than {model.name!r}")
    if contours.n_cams != len(cameras):
        raise ValueError(f"cameras: {len(cameras)} given, contours were computed for {contours.n_cams}")


def _sliding_terms(model, pose, centres, contours, r):
    """Per-point pieces of the sliding term B = e ⊗ w, shapes (n, 3) and (n, 6).

    ``e = R X_θ / (-f_θ)`` and ``w = (C × R n, R n)``.  θ, f_θ, R n and C are constant along
    a ruling, so everything but the (1 + k z) factor of X_θ is computed once per (camera,
    part, side) and gathered with one index."""
    ns = contours.n_samples
    cam, part = contours.cam[::ns], contours.part[::ns]  # per ruling (n_cams * n_parts * 2,)
    th = contours.theta[::ns]
    a, b, k = model.cones[part, 0], model.cones[part, 1], model.cones[part, 2]
    R, t = pose.rotation[part], pose.translation[part]
    C = centres[cam]
    cos, sin = np.cos(th), np.sin(th)
    m = np.einsum("nji,nj->ni", R, C - t)  # camera centre in the part frame
    f_theta = b * m[:, 0] * sin - a * m[:, 1] * cos
    # f_θ² = F² + G² - H² = D at a root: where contours.py finds no real ruling (D below its
    # threshold, the camera inside or on the cone) there is no sliding; those rows are not valid
    F, G, H = -b * m[:, 0], -a * m[:, 1], a * b * (1.0 + k * m[:, 2])
    degenerate = f_theta * f_theta <= 1e-12 * (F * F + G * G + H * H)
    f_theta = np.where(degenerate, np.inf, f_theta)
    per_ruling = np.empty((cam.size, 9))  # e / (1 + k z), C × nw, nw
    per_ruling[:, 0:3] = R[:, :, 0] * (a * sin / f_theta)[:, None] - R[:, :, 1] * (b * cos / f_theta)[:, None]
    nw = R[:, :, 0] * (b * cos)[:, None] + R[:, :, 1] * (a * sin)[:, None] - R[:, :, 2] * (a * b * k)[:, None]
    per_ruling[:, 3:6] = np.cross(C, nw)
    per_ruling[:, 6:9] = nw
    g = per_ruling[r // ns]
    scale = 1.0 + model.cones[contours.part[r], 2] * contours.z[r]
    return g[:, 0:3] * scale[:, None], g[:, 3:9]


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

    Parameters
    ----------
    model, pose, cameras, contours, sliding, rows
        As ``contour_jacobian``.

    Returns
    -------
    ndarray, shape (n, 3, 6)
        ``dY = (A + B) (ω; v)``, columns ω then v (world); n = N or len(rows).
    """
    _check(model, pose, cameras, contours)
    r = _select(contours, rows)
    Y = contours.points[r]
    out = np.zeros((r.size, 3, 6))
    # A = [-[Y]x  I]
    out[:, 0, 1], out[:, 0, 2] = Y[:, 2], -Y[:, 1]
    out[:, 1, 0], out[:, 1, 2] = -Y[:, 2], Y[:, 0]
    out[:, 2, 0], out[:, 2, 1] = Y[:, 1], -Y[:, 0]
    out[:, 0, 3] = out[:, 1, 4] = out[:, 2, 5] = 1.0
    if sliding:
        e, w = _sliding_terms(model, pose, camera_centres(cameras), contours, r)
        out += e[:, :, None] * w[:, None, :]
    return out


def _affects_float(model: BodyModel) -> np.ndarray:
    """``model.affects`` as 0.0 / 1.0, shape (n_parts, n_params) (cheaper to multiply by)."""
    return model.affects.astype(float)


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
    """dY/dΦ = (A + B) J_H of the contour points in the world.

    Parameters
    ----------
    model, pose, cameras, contours, sliding, rows
        As ``contour_jacobian``.

    Returns
    -------
    ndarray, shape (n, 3, n_params)
        Metres per unit parameter; n = N or len(rows).
    """
    r = _select(contours, rows)
    V = contour_motion(model, pose, cameras, contours, sliding=sliding, rows=r)
    J = (V.reshape(-1, 6) @ _screws(model, pose)).reshape(r.size, 3, model.n_params)
    return J * model.affects[contours.part[r]][:, None, :]


def contour_image_motion(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    contours: Contours,
    *,
    sliding: bool = True,
    rows=None,
) -> np.ndarray:
    """J_I (A + B) of the contour points: image velocity per unit screw of the point's part.

    ``contour_jacobian`` is this times the part's screws (``apply_screws``); a caller that combines
    rows (image gradients, directions) can do so here, on 6 columns instead of n_params.

    Parameters
    ----------
    model, pose, cameras, contours, sliding, rows
        As ``contour_jacobian``.

    Returns
    -------
    ndarray, shape (n, 2, 6)
        Pixels per unit screw ``(ω; v)`` (world); n = N or len(rows).
    """
    _check(model, pose, cameras, contours)
    r = _select(contours, rows)
    Y = contours.points[r]
    JI = project_many_with_jacobian(cameras, Y, cam_index=contours.cam[r])[1]  # invalid rows: junk, as their uv
    # J_I A: row j of J_I gives (Y × j, j);  J_I B: (J_I e) ⊗ (C × nw, nw)
    M = np.empty((r.size, 2, 6))
    j0, j1, j2 = JI[:, :, 0], JI[:, :, 1], JI[:, :, 2]
    y0, y1, y2 = Y[:, 0, None], Y[:, 1, None], Y[:, 2, None]
    M[:, :, 0] = y1 * j2 - y2 * j1
    M[:, :, 1] = y2 * j0 - y0 * j2
    M[:, :, 2] = y0 * j1 - y1 * j0
    M[:, :, 3:] = JI
    if sliding:
        e, w = _sliding_terms(model, pose, camera_centres(cameras), contours, r)
        JIe = j0 * e[:, 0, None] + j1 * e[:, 1, None] + j2 * e[:, 2, None]  # (n, 2)
        M += JIe[:, :, None] * w[:, None, :]
    return M


def apply_screws(model: BodyModel, pose: Pose, motion: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Rows of per-screw motion times J_H of their parts.

    ``motion`` row i is a linear functional of the screw of part ``part[i]`` (e.g. one row of
    ``contour_image_motion``); the result is its derivative with respect to the parameters
    (``J_H`` = the parameters' screws, masked by ``model.affects``).

    Parameters
    ----------
    model : BodyModel
    pose : Pose
    motion : ndarray, shape (n, 6)
    part : ndarray of int, shape (n,)

    Returns
    -------
    ndarray, shape (n, n_params)
    """
    J = motion @ _screws(model, pose)
    J *= _affects_float(model)[part]
    return J


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
    model, pose : the body and its pose (``tracker.body.kinematics.forward``)
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
    r = _select(contours, rows)
    M = contour_image_motion(model, pose, cameras, contours, sliding=sliding, rows=r)
    part = np.repeat(contours.part[r], 2)
    return apply_screws(model, pose, M.reshape(-1, 6), part).reshape(r.size, 2, model.n_params)
