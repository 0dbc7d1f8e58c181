"""Extremal contours of the truncated elliptical cones, in closed form (IJCV 2008 §2.3–2.5).

A part's cone in its own frame is (``tracker.body.model``)::

    X(θ, z) = (a cos θ (1 + k z),  b sin θ (1 + k z),  z),   z in [z1, z2].

Its tangents are ``X_θ = (1 + k z) (-a sin θ, b cos θ, 0)`` and
``X_z = (a k cos θ, b k sin θ, 1)``, so ``X_θ × X_z = (1 + k z) n(θ)`` with::

    n(θ) = (b cos θ,  a sin θ,  -a b k)          (outward, independent of z)

The surface is developable: the normal is constant along each ruling.  With the
camera centre ``m = (m1, m2, m3)`` in the part frame, a point is on the contour
generator when the line of sight lies in the tangent plane, ``(X - m)·n = 0``.
Since ``X·n = a b`` for every z, the condition does not depend on z::

    f(θ; m) = a b (1 + k m3) - b m1 cos θ - a m2 sin θ = 0,
    i.e.  F cos θ + G sin θ + H = 0,  F = -b m1,  G = -a m2,  H = a b (1 + k m3).

With ``t = tan(θ/2)`` this is ``(H - F) t² + 2 G t + (H + F) = 0``: two real roots
(two rulings, the two sides of the part's outline) when ``D = F² + G² - H² >= 0``,
none when the camera is inside the (double) cone.  Each root is evaluated in the
form without cancellation, ``θ = 2 atan2(num, den)`` of ``t = num / den``, which
also covers ``H - F = 0`` (the root ``θ = π``).  Side 0 is the root with ``+√D``,
side 1 the one with ``-√D``; each is a continuous function of the pose, so
contour points (at fixed z samples per part) are matched across poses.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from capture.camera import Camera, stack_cameras
from tracker.kernels import contour_points, ruling_angles
from tracker.body.kinematics import Pose
from tracker.body.model import BodyModel
from tracker.imaging.visibility import hidden_points

__all__ = ["Contours", "extremal_contours", "contour_generator_angles", "sample_heights", "camera_centres"]


@dataclass(frozen=True, eq=False)
class Contours:
    """Extremal-contour points of every part seen by every camera.

    Rows are ordered (camera, part, side, sample), row-major:
    ``N = n_cams * n_parts * 2 * n_samples``.

    Attributes
    ----------
    n_cams, n_parts, n_samples : int
    cam, part, side : ndarray of int, shape (N,)
    z : ndarray, shape (N,)
        Axial coordinate of the point in its part frame, metres (fixed per part).
    theta : ndarray, shape (N,)
        Angle of the contour generator on the cone, radians.
    points : ndarray, shape (N, 3)
        World coordinates, metres.
    uv : ndarray, shape (N, 2)
        Pixel coordinates (``Camera.project``) where ``valid``; 0 elsewhere (always finite).
    valid : ndarray of bool, shape (N,)
        The camera is outside the cone (a real contour generator), the point is in
        front of the camera and inside the image.
    visible : ndarray of bool, shape (N,)
        ``valid`` and not hidden behind another part from that camera (equals
        ``valid`` when computed with ``visibility=False``).
    """

    n_cams: int
    n_parts: int
    n_samples: int
    cam: np.ndarray
    part: np.ndarray
    side: np.ndarray
    z: np.ndarray
    theta: np.ndarray
    points: np.ndarray
    uv: np.ndarray
    valid: np.ndarray
    visible: np.ndarray

    @property
    def n_points(self) -> int:
        return self.cam.shape[0]

    def shaped(self, values: np.ndarray) -> np.ndarray:
        """View per-row ``values`` (N, ...) as (n_cams, n_parts, 2, n_samples, ...)."""
        return values.reshape(self.n_cams, self.n_parts, 2, self.n_samples, *values.shape[1:])


@lru_cache(maxsize=16)
def _row_indices(shape: tuple) -> np.ndarray:
    """(cam, part, side, sample) of every row, shape (4, N), read-only (cached per layout)."""
    idx = np.indices(shape).reshape(4, -1)
    idx.setflags(write=False)
    return idx


@lru_cache(maxsize=32)
def _layout(model: BodyModel, n_samples: int, cameras: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per (model, n_samples, cameras), read-only: the sample heights (n_parts, n_samples), the
    height of every row (N,) and the image sizes (n_cams, 2)."""
    zs = sample_heights(model, n_samples)
    shape = (len(cameras), model.n_parts, 2, n_samples)
    z_rows = np.ascontiguousarray(np.broadcast_to(zs[None, :, None, :], shape).reshape(-1))
    size = np.array([cam.size for cam in cameras], dtype=float)
    for arr in (zs, z_rows, size):
        arr.setflags(write=False)
    return zs, z_rows, size


def sample_heights(model: BodyModel, n_samples: int) -> np.ndarray:
    """The fixed axial sample positions of every part, shape (n_parts, n_samples), metres.

    Midpoints of ``n_samples`` equal slices of ``[z1, z2]`` (the end rings are left out).
    """
    z1, z2 = model.cones[:, 3], model.cones[:, 4]
    frac = (np.arange(n_samples) + 0.5) / n_samples
    return z1[:, None] + (z2 - z1)[:, None] * frac[None, :]


def camera_centres(cameras: Sequence[Camera]) -> np.ndarray:
    """Optical centres in world coordinates, shape (n_cams, 3)."""
    return np.array([c.center for c in cameras], dtype=float).reshape(-1, 3)


def contour_generator_angles(cones: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Angles θ of the two contour generators of cones seen from points m.

    Parameters
    ----------
    cones : ndarray, shape (..., 5)
        ``(a, b, k, z1, z2)`` per cone.
    m : ndarray, shape (..., 3)
        Camera centre in the cone's part frame (broadcast against ``cones``).

    Returns
    -------
    theta : ndarray, shape (..., 2)
        Side 0 (root with +√D), side 1 (root with -√D); finite everywhere.
    real : ndarray of bool, shape (...)
        ``D > 0``: the camera is outside the cone, the rulings exist.  Where it is
        not, ``theta`` holds the (finite) angles computed with ``D`` clipped to 0.
    """
    # F = -b m1, G = -a m2, H = a b (1 + k m3), D = F² + G² - H²; t± = (-G ± √D) / (H - F) =
    # (H + F) / (-G ∓ √D), each root taken in the form whose numerator does not cancel
    # (tracker.kernels.projection._ruling_angles)
    cones, m = np.broadcast_arrays(np.asarray(cones, dtype=float)[..., :3], np.asarray(m, dtype=float))
    shape = m.shape[:-1]
    theta, real = ruling_angles(np.ascontiguousarray(cones.reshape(-1, 3)), np.ascontiguousarray(m.reshape(-1, 3)))
    return theta.reshape(shape + (2,)), real.reshape(shape)


def extremal_contours(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    *,
    n_samples: int = 20,
    visibility: bool = True,
) -> Contours:
    """Sample the two contour generators of every part seen from every camera.

    Parameters
    ----------
    model : BodyModel
    pose : Pose
        From ``tracker.body.kinematics.forward``.
    cameras : sequence of Camera, length n_cams
    n_samples : int
        Points per ruling (at the fixed heights of ``sample_heights``).
    visibility : bool
        Flag points hidden by other parts (``tracker.imaging.visibility``); when False,
        ``visible`` equals ``valid``.

    Returns
    -------
    Contours
        ``N = n_cams * n_parts * 2 * n_samples`` rows.
    """
    if n_samples < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras: at least one camera is needed")
    if pose.rotation.shape[0] != model.n_parts:
        raise ValueError(f"pose: has {pose.rotation.shape[0]} parts, model {model.name!r} has {model.n_parts}")
    n_cams, n_parts = len(cameras), model.n_parts
    zs, z_rows, size = _layout(model, n_samples, tuple(cameras))
    st = stack_cameras(cameras)  # world2cam rotations (n_cams, 3, 3), translations (n_cams, 3), intrinsics
    # per (camera, part): the rulings' angles from the camera centre in the part frame (module
    # docstring); per sample: world point (1 + k z) (a cos θ R e1 + b sin θ R e2) + z R e3 + t,
    # projected (tracker.kernels.contour_points)
    theta, points, uv, valid = contour_points(model.cones, pose.rotation, pose.translation, zs, st.rotation,
                                              st.translation, st.intrinsics, st.distortion, size)
    shape = (n_cams, n_parts, 2, n_samples)
    idx = _row_indices(shape)
    visible = valid
    if visibility:
        visible = valid & ~hidden_points(model, pose, cameras, idx[0], idx[1], points, only=valid)
    return Contours(
        n_cams=n_cams,
        n_parts=n_parts,
        n_samples=n_samples,
        cam=idx[0],
        part=idx[1],
        side=idx[2],
        z=z_rows,
        theta=theta,
        points=points,
        uv=uv,
        valid=valid,
        visible=visible,
    )
