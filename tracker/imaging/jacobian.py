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

from capture.camera import Camera, stack_cameras
from tracker.imaging.contours import Contours
from tracker.kernels import image_motion, projection_jacobians, screw_rows
from tracker.body.kinematics import Pose, parameter_screws
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


def _motion(model, pose, cameras, contours, r, JI, sliding):
    """``JI (A + B)`` of contour rows ``r`` (n,) for per-row Jacobians ``JI`` (n, d, 3), (n, d, 6)
    (``tracker.kernels.image_motion``: the sliding term B = e ⊗ w with ``e = R X_θ / (-f_θ)`` and
    ``w = (C × R n, R n)``; none where f_θ² is below its threshold: no real ruling, those rows are
    not valid)."""
    st = stack_cameras(cameras)
    return image_motion(np.ascontiguousarray(contours.points[r]), np.ascontiguousarray(JI), contours.cam[r],
                        contours.part[r], contours.z[r], contours.theta[r], model.cones, pose.rotation,
                        pose.translation, st.rotation, st.translation, bool(sliding))


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
    return _motion(model, pose, cameras, contours, r, np.broadcast_to(np.eye(3), (r.size, 3, 3)), sliding)


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
    return apply_screws(model, pose, V.reshape(-1, 6), np.repeat(contours.part[r], 3)).reshape(r.size, 3, model.n_params)


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
    # J_I A: row j of J_I gives (Y × j, j);  J_I B: (J_I e) ⊗ (C × nw, nw)
    st = stack_cameras(cameras)
    JI = projection_jacobians(st.rotation, st.translation, st.intrinsics, st.distortion,
                              np.ascontiguousarray(contours.points[r]), contours.cam[r])  # invalid rows: junk
    return _motion(model, pose, cameras, contours, r, JI, sliding)


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
    return screw_rows(np.ascontiguousarray(motion, dtype=float), np.asarray(part, dtype=np.intp),
                      np.ascontiguousarray(parameter_screws(pose)), model.affects)


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
