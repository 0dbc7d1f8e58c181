"""Pinhole camera with OpenCV distortion: the one camera model of contourcap.

World frame: metres, right-handed, Z up, floor at z = 0.  ``rotation`` and
``translation`` map world to camera (OpenCV convention: x right, y down, z
forward), so ``X_cam = R @ X_world + t``.

Distortion follows OpenCV's order ``(k1, k2, p1, p2, k3)``::

    x, y   = X_cam[0] / X_cam[2], X_cam[1] / X_cam[2]
    r2     = x² + y²
    radial = 1 + k1 r2 + k2 r2² + k3 r2³
    xd     = x radial + 2 p1 x y + p2 (r2 + 2 x²)
    yd     = y radial + p1 (r2 + 2 y²) + 2 p2 x y
    u, v   = K @ (xd, yd, 1)

``project_with_jacobian`` also returns the exact 2×3 derivative of ``(u, v)``
with respect to the world point (the J_I factor of the extremal-contour
Jacobian); ``tests/test_camera.py`` checks it against finite differences.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np

__all__ = [
    "Camera",
    "CameraStack",
    "stack_cameras",
    "project_many",
    "project_many_with_jacobian",
    "rodrigues_to_matrix",
    "matrix_to_rodrigues",
]


def _as_distortion(dist) -> np.ndarray:
    d = np.zeros(5)
    arr = np.asarray(dist, dtype=float).ravel()
    if arr.size not in (0, 4, 5):
        raise ValueError(f"distortion must have 4 or 5 terms (k1, k2, p1, p2[, k3]), got {arr.size}")
    d[: arr.size] = arr
    return d


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera.

    Parameters
    ----------
    name : str
    matrix : ndarray, shape (3, 3)
        Intrinsics K in pixels.
    distortion : ndarray, shape (5,)
        OpenCV ``(k1, k2, p1, p2, k3)``; 4 terms are accepted (k3 = 0).
    rotation : ndarray, shape (3, 3)
        world2cam rotation matrix.
    translation : ndarray, shape (3,)
        world2cam translation, metres.
    size : tuple of int
        Image ``(width, height)`` in pixels.
    """

    name: str
    matrix: np.ndarray
    distortion: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    size: tuple[int, int]

    def __post_init__(self):
        K = np.array(self.matrix, dtype=float).reshape(3, 3)
        R = np.array(self.rotation, dtype=float)
        if R.shape == (3,):
            R = rodrigues_to_matrix(R)
        R = R.reshape(3, 3)
        t = np.array(self.translation, dtype=float).reshape(3)
        if not np.all(np.isfinite(K)) or not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
            raise ValueError(f"camera {self.name!r}: non-finite calibration values")
        if abs(K[2, 2] - 1.0) > 1e-9 or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"camera {self.name!r}: matrix must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError(f"camera {self.name!r}: rotation is not a proper rotation matrix")
        w, h = (int(v) for v in self.size)
        if w <= 0 or h <= 0:
            raise ValueError(f"camera {self.name!r}: size must be positive (width, height), got {self.size}")
        for arr in (K, R, t):
            arr.setflags(write=False)
        d = _as_distortion(self.distortion)
        d.setflags(write=False)
        object.__setattr__(self, "matrix", K)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)
        object.__setattr__(self, "distortion", d)
        object.__setattr__(self, "size", (w, h))

    # ------------------------------------------------------------------ frames
    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def center(self) -> np.ndarray:
        """Optical centre in world coordinates, shape (3,)."""
        return -self.rotation.T @ self.translation

    @property
    def world2cam(self) -> np.ndarray:
        """Homogeneous world2cam transform, shape (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation
        return T

    @property
    def rvec(self) -> np.ndarray:
        """Rodrigues vector of the world2cam rotation, shape (3,)."""
        return matrix_to_rodrigues(self.rotation)

    @property
    def projection_matrix(self) -> np.ndarray:
        """P = K [R | t], shape (3, 4) (ignores distortion)."""
        return self.matrix @ self.world2cam[:3]

    def to_camera(self, points_world: np.ndarray) -> np.ndarray:
        """World points (..., 3) -> camera-frame points (..., 3)."""
        return np.asarray(points_world, dtype=float) @ self.rotation.T + self.translation

    # -------------------------------------------------------------- projection
    def _distort(self, x, y):
        k1, k2, p1, p2, k3 = self.distortion
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return xd, yd, r2, radial

    def project(self, points_world: np.ndarray) -> np.ndarray:
        """Project world points.

        Parameters
        ----------
        points_world : ndarray, shape (..., 3)

        Returns
        -------
        ndarray, shape (..., 2)
            Pixel coordinates (u, v).  Points at or behind the camera plane
            give non-finite or meaningless values: check ``depth`` first.
        """
        Xc = self.to_camera(points_world)
        z = Xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = Xc[..., 0] / z
            y = Xc[..., 1] / z
        xd, yd, _, _ = self._distort(x, y)
        K = self.matrix
        return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)

    def rays(self, uv: np.ndarray) -> np.ndarray:
        """Unit world directions (n, 3) of the rays from the centre through pixels ``uv`` (n, 2).

        Distortion is inverted with ``cv2.undistortPoints`` (iterative, to 1e-10), so a ray projects
        back to its pixel.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not len(uv):
            return np.zeros((0, 3))
        if np.any(self.distortion != 0):
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10)
            xy = cv2.undistortPoints(uv.reshape(-1, 1, 2), self.matrix, self.distortion, criteria=crit).reshape(-1, 2)
        else:
            Kinv = np.linalg.inv(self.matrix)
            xy = uv @ Kinv[:2, :2].T + Kinv[:2, 2]
        d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ self.rotation  # rows: R^T d_cam
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def depth(self, points_world: np.ndarray) -> np.ndarray:
        """Camera-frame z of world points, shape (...)."""
        return self.to_camera(points_world)[..., 2]

    def project_with_jacobian(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points and differentiate.

        Parameters
        ----------
        points_world : ndarray, shape (..., 3)

        Returns
        -------
        uv : ndarray, shape (..., 2)
        jac : ndarray, shape (..., 2, 3)
            d(u, v) / d(X_world).
        """
        Xc = self.to_camera(points_world)
        z = Xc[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = 1.0 / z
        x = Xc[..., 0] * inv_z
        y = Xc[..., 1] * inv_z
        k1, k2, p1, p2, k3 = self.distortion
        xd, yd, r2, radial = self._distort(x, y)
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)  # d radial / d r2
        dxd_dx = radial + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        dxd_dy = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        dyd_dx = dxd_dy  # the distortion map's Jacobian is symmetric
        dyd_dy = radial + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        K = self.matrix
        # d(u, v)/d(x, y): K's upper 2x2 times the distortion Jacobian
        du_dx = K[0, 0] * dxd_dx + K[0, 1] * dyd_dx
        du_dy = K[0, 0] * dxd_dy + K[0, 1] * dyd_dy
        dv_dx = K[1, 1] * dyd_dx
        dv_dy = K[1, 1] * dyd_dy
        # d(x, y)/d(Xc) = [[1/z, 0, -x/z], [0, 1/z, -y/z]]
        d_uv_dXc = np.stack(
            [
                np.stack([du_dx * inv_z, du_dy * inv_z, -(du_dx * x + du_dy * y) * inv_z], axis=-1),
                np.stack([dv_dx * inv_z, dv_dy * inv_z, -(dv_dx * x + dv_dy * y) * inv_z], axis=-1),
            ],
            axis=-2,
        )
        jac = d_uv_dXc @ self.rotation  # (..., 2, 3) @ (3, 3): chain rule through X_c = R X + t
        uv = np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)
        return uv, jac

    def in_image(self, uv: np.ndarray, *, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixel positions (..., 2) inside the image."""
        u, v = uv[..., 0], uv[..., 1]
        return (u >= -margin) & (v >= -margin) & (u <= self.width - 1 + margin) & (v <= self.height - 1 + margin)

    def with_name(self, name: str) -> "Camera":
        """The same camera under another name."""
        return Camera(name, self.matrix, self.distortion, self.rotation, self.translation, self.size)

    @classmethod
    def look_at(
        cls,
        name: str,
        eye,
        target,
        *,
        size: tuple[int, int] = (800, 600),
        fov_deg: float = 60.0,
        distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
        up=(0.0, 0.0, 1.0),
    ) -> "Camera":
        """A camera at ``eye`` (world, metres) looking at ``target``, image up ≈ world ``up``.

        ``fov_deg`` is the horizontal field of view.
        """
        eye = np.asarray(eye, dtype=float)
        fwd = np.asarray(target, dtype=float) - eye
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(up, dtype=float))
        if np.linalg.norm(right) < 1e-9:
            raise ValueError(f"camera {name!r}: viewing direction is parallel to 'up'")
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd])  # rows: camera axes in world
        w, h = size
        f = 0.5 * w / np.tan(np.radians(fov_deg) / 2.0)
        K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(name, K, np.asarray(distortion, dtype=float), R, -R @ eye, (w, h))


@dataclass(frozen=True, eq=False)
class CameraStack:
    """The calibrations of several cameras stacked for batch projection (read-only arrays).

    ``rotation (n_cams, 3, 3)`` world2cam, ``translation (n_cams, 3)``, ``intrinsics (n_cams, 5)``
    = ``(fx, skew, cx, fy, cy)``, ``distortion (n_cams, 5)``; ``distorted`` is False when every
    camera's distortion is exactly zero (the distortion polynomial is then skipped: it would
    return its input unchanged), ``skewed`` likewise for the skew term.
    """

    rotation: np.ndarray
    translation: np.ndarray
    intrinsics: np.ndarray
    distortion: np.ndarray
    distorted: bool
    skewed: bool


@lru_cache(maxsize=32)
def _stack(cameras: tuple) -> CameraStack:
    R = np.stack([c.rotation for c in cameras])
    t = np.stack([c.translation for c in cameras])
    K = np.stack([c.matrix[[0, 0, 0, 1, 1], [0, 1, 2, 1, 2]] for c in cameras])
    d = np.stack([c.distortion for c in cameras])
    for arr in (R, t, K, d):
        arr.setflags(write=False)
    return CameraStack(R, t, K, d, bool(np.any(d != 0.0)), bool(np.any(K[:, 1] != 0.0)))


def stack_cameras(cameras: Sequence[Camera]) -> CameraStack:
    """Stacked calibration arrays of ``cameras`` (cached per tuple of Camera objects)."""
    cameras = tuple(cameras)
    if not cameras:
        raise ValueError("cameras: at least one camera is needed")
    return _stack(cameras)


def _batch_camera_frame(st: CameraStack, points_world, cam_index):
    """Camera-frame points and the per-point parameter selector.

    ``cam_index`` None: ``points_world (n_cams, n, 3)``, camera c's rows in slab c; parameters
    are broadcast as ``(n_cams, 1)``.  Else ``points_world (n, 3)`` and ``cam_index (n,)``."""
    X = np.asarray(points_world, dtype=float)
    n_cams = st.rotation.shape[0]
    if cam_index is None:
        if X.ndim != 3 or X.shape[0] != n_cams or X.shape[2] != 3:
            raise ValueError(f"points_world: expected shape ({n_cams}, n, 3) without cam_index, got {X.shape}")
        Xc = np.matmul(X, st.rotation.transpose(0, 2, 1))
        Xc += st.translation[:, None, :]
        return Xc, (slice(None), None), st.rotation[:, None]
    idx = np.asarray(cam_index)
    if X.ndim != 2 or X.shape[1] != 3 or idx.shape != X.shape[:1]:
        raise ValueError(f"points_world (n, 3) and cam_index (n,) expected, got {X.shape} and {idx.shape}")
    if idx.size and (idx.min() < 0 or idx.max() >= n_cams):
        raise ValueError(f"cam_index: values must lie in [0, {n_cams})")
    R = st.rotation[idx]
    Xc = np.matmul(R, X[:, :, None])[:, :, 0]
    Xc += st.translation[idx]
    return Xc, idx, R


def _batch_project(st: CameraStack, Xc, sel, jacobian: bool, R=None):
    K = st.intrinsics[sel]  # (n_cams, 1, 5) or (n, 5): broadcast against (..., ) below
    fx, sk, cx, fy, cy = K[..., 0], K[..., 1], K[..., 2], K[..., 3], K[..., 4]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_z = 1.0 / Xc[..., 2]
    x = Xc[..., 0] * inv_z
    y = Xc[..., 1] * inv_z
    shape = x.shape
    uv = np.empty(shape + (2,))
    if st.distorted:
        d = st.distortion[sel]
        k1, k2, p1, p2, k3 = d[..., 0], d[..., 1], d[..., 2], d[..., 3], d[..., 4]
        xy = x * y
        xx, yy = x * x, y * y
        r2 = xx + yy
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * xx)
        yd = y * radial + p1 * (r2 + 2.0 * yy) + 2.0 * p2 * xy
    else:
        xd, yd = x, y
    if st.skewed:
        np.add(fx * xd + sk * yd, cx, out=uv[..., 0])
    else:
        np.add(fx * xd, cx, out=uv[..., 0])
    np.add(fy * yd, cy, out=uv[..., 1])
    if not jacobian:
        return uv, None
    if st.distorted:
        drad = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
        dxd_dx = radial + 2.0 * xx * drad + 2.0 * p1 * y + 6.0 * p2 * x
        dxd_dy = 2.0 * xy * drad + 2.0 * p1 * x + 2.0 * p2 * y
        dyd_dy = radial + 2.0 * yy * drad + 6.0 * p1 * y + 2.0 * p2 * x
        du_dx = fx * dxd_dx + sk * dxd_dy
        du_dy = fx * dxd_dy + sk * dyd_dy
        dv_dx = fy * dxd_dy
        dv_dy = fy * dyd_dy
    else:
        du_dx, du_dy, dv_dx, dv_dy = fx, sk, 0.0, fy
    D = np.empty(shape + (2, 3))
    D[..., 0, 0] = du_dx * inv_z
    D[..., 0, 1] = du_dy * inv_z
    D[..., 0, 2] = -(du_dx * x + du_dy * y) * inv_z
    D[..., 1, 0] = dv_dx * inv_z
    D[..., 1, 1] = dv_dy * inv_z
    D[..., 1, 2] = -(dv_dx * x + dv_dy * y) * inv_z
    return uv, np.matmul(D, R)


def project_many(cameras: Sequence[Camera], points_world, cam_index=None) -> np.ndarray:
    """Project points with several cameras at once (equals ``Camera.project`` per camera).

    Parameters
    ----------
    cameras : sequence of Camera, length n_cams (stacked arrays cached per tuple)
    points_world : ndarray, shape (n_cams, n, 3), or (n, 3) with ``cam_index``
        World points, metres; slab c is seen by camera c.
    cam_index : ndarray of int, shape (n,), optional
        The camera of every point (instead of one slab per camera).

    Returns
    -------
    ndarray, shape (n_cams, n, 2) or (n, 2)
        Pixels; points at or behind a camera give junk (check the depth first).
    """
    st = stack_cameras(cameras)
    Xc, sel, _ = _batch_camera_frame(st, points_world, cam_index)
    with np.errstate(all="ignore"):
        return _batch_project(st, Xc, sel, False)[0]


def project_many_with_jacobian(cameras: Sequence[Camera], points_world, cam_index=None):
    """``project_many`` and d(u, v)/d(X_world), shapes (..., 2) and (..., 2, 3).

    Equals ``Camera.project_with_jacobian`` per camera; same layouts as ``project_many``.
    """
    st = stack_cameras(cameras)
    Xc, sel, R = _batch_camera_frame(st, points_world, cam_index)
    with np.errstate(all="ignore"):
        return _batch_project(st, Xc, sel, True, R)


def rodrigues_to_matrix(rvec) -> np.ndarray:
    """Rodrigues vector (3,) -> rotation matrix (3, 3)."""
    r = np.asarray(rvec, dtype=float).reshape(3)
    theta = np.linalg.norm(r)
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * Kx + (1 - np.cos(theta)) * (Kx @ Kx)


def matrix_to_rodrigues(R) -> np.ndarray:
    """Rotation matrix (3, 3) -> Rodrigues vector (3,) (angle in [0, π])."""
    R = np.asarray(R, dtype=float)
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos)
    if theta < 1e-12:
        return np.zeros(3)
    if np.pi - theta < 1e-6:
        # axis from the symmetric part: R = 2 k k^T - I
        M = (R + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(M)))
        k = M[:, i] / np.sqrt(M[i, i])
        return k * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / (2.0 * np.sin(theta))
    return w * theta
