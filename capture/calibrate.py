"""Camera calibration from boards: intrinsics per camera, extrinsics in one floor-board world frame.

World frame (DESIGN.md): metres, Z up, floor at z = 0.  The *floor board*
(placement 0) lies on the floor and defines it: origin at its corner ``(0, 0)``
(see ``capture.board``), x and y along its edges, assigned so that z points
up, towards the cameras.  Further board placements (a board moved around and
seen by several cameras at once) may be added; their poses are unknowns of
the bundle adjustment, which refines every camera's world2cam pose and every
extra placement's board2world pose together by minimising the reprojection
error of all corners (``scipy.optimize.least_squares`` with a sparse
``jac_sparsity``: each corner depends on one camera and one placement).
Intrinsics are held fixed during extrinsic calibration.

Solvers return frozen result objects and never print; ``progress`` callbacks
are the caller's (the CLI draws a bar on stderr).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from capture.camera import Camera, matrix_to_rodrigues, rodrigues_to_matrix

__all__ = [
    "Intrinsics",
    "IntrinsicsResult",
    "BoardObservation",
    "CameraReport",
    "ExtrinsicsResult",
    "calibrate_intrinsics",
    "intrinsics_from_frames",
    "calibrate_extrinsics",
    "rodrigues_batch",
    "solve_board_pose",
]

Progress = Callable[[int, int, str], None]


@dataclass(frozen=True)
class Intrinsics:
    """One camera's intrinsics: ``matrix`` K (3, 3), OpenCV ``distortion`` (5,), image ``size`` (w, h)."""

    name: str
    matrix: np.ndarray
    distortion: np.ndarray
    size: tuple[int, int]

    @classmethod
    def from_camera(cls, cam: Camera) -> "Intrinsics":
        """The intrinsic part of a calibrated camera."""
        return cls(cam.name, cam.matrix, cam.distortion, cam.size)


@dataclass(frozen=True)
class IntrinsicsResult:
    """``calibrate_intrinsics`` output: the intrinsics, overall and per-view RMS reprojection error (px)."""

    intrinsics: Intrinsics
    rms_px: float
    per_view_rms_px: tuple[float, ...]
    n_views: int


def calibrate_intrinsics(
    name: str,
    image_points: Sequence[np.ndarray],
    object_points: Sequence[np.ndarray],
    size: tuple[int, int],
    *,
    fix_k3: bool = False,
) -> IntrinsicsResult:
    """``cv2.calibrateCamera`` over several board views of one camera.

    Parameters
    ----------
    image_points : list of ndarray, shape (n_i, 2)
        Raw pixel corners per view.
    object_points : list of ndarray, shape (n_i, 3)
        Matching board-frame corners (metres).
    size : (width, height)
    """
    if len(image_points) != len(object_points):
        raise ValueError(f"camera {name!r}: {len(image_points)} image point sets but {len(object_points)} object point sets")
    if len(image_points) < 3:
        raise ValueError(f"camera {name!r}: intrinsic calibration needs at least 3 board views, got {len(image_points)}")
    img = [np.asarray(p, dtype=np.float32).reshape(-1, 1, 2) for p in image_points]
    obj = [np.asarray(p, dtype=np.float32).reshape(-1, 1, 3) for p in object_points]
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, tuple(int(v) for v in size), None, None, flags=flags)
    per_view = []
    for o, i, r, t in zip(obj, img, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        per_view.append(float(np.sqrt(np.mean(np.sum((proj - i).reshape(-1, 2) ** 2, axis=1)))))
    intr = Intrinsics(name, K, np.asarray(dist, dtype=float).ravel()[:5], (int(size[0]), int(size[1])))
    return IntrinsicsResult(intr, float(rms), tuple(per_view), len(img))


def intrinsics_from_frames(
    name: str,
    frames: Sequence[np.ndarray],
    board,
    *,
    max_views: int = 40,
    progress: Progress | None = None,
) -> IntrinsicsResult:
    """Detect ``board`` (``Checkerboard`` or ``CharucoBoard``) in grey frames (h, w) and calibrate.

    At most ``max_views`` detections, spread evenly over the frames, go into
    ``cv2.calibrateCamera``; fewer than 3 raises a ``ValueError`` naming the camera.
    """
    from capture.board import detect_board

    if not frames:
        raise ValueError(f"camera {name!r}: no frames to calibrate from")
    if max_views < 3:
        raise ValueError(f"max_views: need at least 3 board views, got {max_views}")
    size = (int(frames[0].shape[1]), int(frames[0].shape[0]))
    other = next((k for k, f in enumerate(frames) if f.shape[:2] != frames[0].shape[:2]), None)
    if other is not None:  # one K cannot fit views of different image sizes
        raise ValueError(f"camera {name!r}: frame {other} is {frames[other].shape[1]}x{frames[other].shape[0]}, "
                         f"frame 0 is {size[0]}x{size[1]}; all views must have the same size")
    found = []
    for k, f in enumerate(frames):
        if progress:
            progress(k, len(frames), f"{name}: detecting board")
        d = detect_board(f, board)
        if d is not None:
            found.append(d)
    if progress:
        progress(len(frames), len(frames), f"{name}: calibrating")
    if len(found) < 3:
        raise ValueError(f"camera {name!r}: board found in {len(found)} of {len(frames)} frames; need at least 3")
    pick = np.unique(np.linspace(0, len(found) - 1, min(max_views, len(found))).round().astype(int))
    return calibrate_intrinsics(name, [found[i][0] for i in pick], [found[i][1] for i in pick], size)


@dataclass(frozen=True)
class BoardObservation:
    """Corners of one board placement seen by one camera.

    image_points : ndarray, shape (n, 2)  raw pixels
    object_points : ndarray, shape (n, 3)  board frame, metres (z = 0)
    placement : int  0 = the floor board defining the world; others are free poses
    method : str  "detected" or "manual" (from a user outline)
    frames : tuple of int  video frames the corners came from
    """

    camera: str
    placement: int
    image_points: np.ndarray
    object_points: np.ndarray
    method: str = "detected"
    frames: tuple[int, ...] = ()


@dataclass(frozen=True)
class CameraReport:
    """What happened to one camera: used or not (with the reason), how, and its RMS error (px)."""

    name: str
    used: bool
    method: str = ""
    frames: tuple[int, ...] = ()
    n_points: int = 0
    rms_px: float = float("nan")
    reason: str = ""


@dataclass(frozen=True)
class ExtrinsicsResult:
    """Bundle-adjusted extrinsics.

    cameras : calibrated cameras (world2cam, metres), in the order given, failed cameras left out
    reports : one ``CameraReport`` per camera given (failed ones say why)
    placements : board2world (4, 4) per placement id (0 is the identity)
    rms_px : overall RMS reprojection error
    """

    cameras: tuple[Camera, ...]
    reports: tuple[CameraReport, ...]
    placements: Mapping[int, np.ndarray] = field(default_factory=dict)
    rms_px: float = float("nan")
    iterations: int = 0
    status: int = 0
    message: str = ""

    @property
    def failed(self) -> dict[str, str]:
        return {r.name: r.reason for r in self.reports if not r.used}


def rodrigues_batch(rvecs: np.ndarray) -> np.ndarray:
    """Rodrigues vectors (m, 3) -> rotation matrices (m, 3, 3)."""
    r = np.asarray(rvecs, dtype=float).reshape(-1, 3)
    theta = np.linalg.norm(r, axis=1)
    safe = np.where(theta < 1e-12, 1.0, theta)
    k = r / safe[:, None]
    Kx = np.zeros((len(r), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2] = -k[:, 2], k[:, 1]
    Kx[:, 1, 0], Kx[:, 1, 2] = k[:, 2], -k[:, 0]
    Kx[:, 2, 0], Kx[:, 2, 1] = -k[:, 1], k[:, 0]
    s = np.where(theta < 1e-12, 0.0, np.sin(theta))[:, None, None]
    c = np.where(theta < 1e-12, 0.0, 1.0 - np.cos(theta))[:, None, None]
    return np.eye(3)[None] + s * Kx + c * (Kx @ Kx)


def _project(K: np.ndarray, dist: np.ndarray, Xc: np.ndarray) -> np.ndarray:
    """Per-point projection: K (m, 3, 3), dist (m, 5), camera points Xc (m, 3) -> pixels (m, 2)."""
    x, y = Xc[:, 0] / Xc[:, 2], Xc[:, 1] / Xc[:, 2]
    k1, k2, p1, p2, k3 = dist.T
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([K[:, 0, 0] * xd + K[:, 0, 1] * yd + K[:, 0, 2], K[:, 1, 1] * yd + K[:, 1, 2]], axis=-1)


def solve_board_pose(obs: BoardObservation, intr: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """board2cam pose (rvec (3,), tvec (3,) metres) from one observation: planar IPPE, then iterative refinement."""
    obj = np.asarray(obs.object_points, dtype=np.float64)
    img = np.asarray(obs.image_points, dtype=np.float64)
    ok, rv, tv = cv2.solvePnP(obj, img, intr.matrix, intr.distortion, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise ValueError("solvePnP failed")
    ok, rv, tv = cv2.solvePnP(obj, img, intr.matrix, intr.distortion, rv, tv, True, flags=cv2.SOLVEPNP_ITERATIVE)
    return rv.ravel(), tv.ravel()


def _to_T(rv, tv) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rodrigues_to_matrix(rv)
    T[:3, 3] = tv
    return T


def _initial_poses(intr: Mapping[str, Intrinsics], obs: Sequence[BoardObservation]):
    """world2cam per camera and board2world per placement by chaining PnP poses outwards from placement 0."""
    board2cam = {(o.camera, o.placement): _to_T(*solve_board_pose(o, intr[o.camera])) for o in obs}
    cams: dict[str, np.ndarray] = {c: T for (c, p), T in board2cam.items() if p == 0}
    places: dict[int, np.ndarray] = {0: np.eye(4)}
    changed = True
    while changed:
        changed = False
        for (c, p), T in board2cam.items():
            if c in cams and p not in places:
                places[p] = np.linalg.inv(cams[c]) @ T
                changed = True
            elif p in places and c not in cams:
                cams[c] = T @ np.linalg.inv(places[p])
                changed = True
    return cams, places


def calibrate_extrinsics(
    intrinsics: Sequence[Intrinsics],
    observations: Sequence[BoardObservation],
    *,
    failures: Mapping[str, str] | None = None,
    progress: Progress | None = None,
) -> ExtrinsicsResult:
    """Joint extrinsic calibration from board observations (see module doc).

    A camera with no observation, or one not linked to the floor board
    through shared placements, is reported with the reason (``failures``
    supplies reasons found earlier, e.g. "board not found in 5 frames").
    """
    intr = {i.name: i for i in intrinsics}
    failures = dict(failures or {})
    for o in observations:
        if o.camera not in intr:
            raise ValueError(f"observation for unknown camera {o.camera!r}")
        if len(o.image_points) != len(o.object_points) or len(o.image_points) < 4:
            raise ValueError(f"camera {o.camera!r}, placement {o.placement}: need >= 4 matching points")
    obs = [o for o in observations if o.camera not in failures]
    cams0, places0 = _initial_poses(intr, obs)
    for name in intr:
        if name not in cams0 and name not in failures:
            seen = any(o.camera == name for o in obs)
            failures[name] = ("board placements it saw are not linked to the floor board by any other camera"
                              if seen else "no board observation")
    obs = [o for o in obs if o.camera in cams0 and o.placement in places0]
    cam_names = [n for n in intr if n in cams0]
    place_ids = sorted({o.placement for o in obs} - {0})
    ci = {n: k for k, n in enumerate(cam_names)}
    pi = {p: k for k, p in enumerate(place_ids)}
    nc, npl = len(cam_names), len(place_ids)
    if nc == 0:
        reports = tuple(CameraReport(n, False, reason=failures.get(n, "no board observation")) for n in intr)
        return ExtrinsicsResult((), reports, {0: np.eye(4)}, status=-1, message="no camera could be calibrated")

    # stacked per-point data: camera index, placement index (-1 = floor), observed pixel, board point
    cam_idx = np.concatenate([np.full(len(o.image_points), ci[o.camera]) for o in obs])
    pl_idx = np.concatenate([np.full(len(o.image_points), pi.get(o.placement, -1)) for o in obs])
    uv = np.concatenate([np.asarray(o.image_points, dtype=float) for o in obs])
    Xb = np.concatenate([np.asarray(o.object_points, dtype=float) for o in obs])
    Ks = np.stack([intr[n].matrix for n in cam_names])[cam_idx]
    Ds = np.stack([np.asarray(intr[n].distortion, dtype=float) for n in cam_names])[cam_idx]
    floor = pl_idx < 0

    x0 = np.concatenate(
        [np.r_[matrix_to_rodrigues(cams0[n][:3, :3]), cams0[n][:3, 3]] for n in cam_names]
        + [np.r_[matrix_to_rodrigues(places0[p][:3, :3]), places0[p][:3, 3]] for p in place_ids]
    )

    def residuals(x):
        cp = x[: 6 * nc].reshape(nc, 6)
        Rc = rodrigues_batch(cp[:, :3])
        Xw = Xb.copy()
        if npl:
            pp = x[6 * nc:].reshape(npl, 6)
            Rp = rodrigues_batch(pp[:, :3])
            m = ~floor
            Xw[m] = np.einsum("nij,nj->ni", Rp[pl_idx[m]], Xb[m]) + pp[pl_idx[m], 3:]
        Xc = np.einsum("nij,nj->ni", Rc[cam_idx], Xw) + cp[cam_idx, 3:]
        return (_project(Ks, Ds, Xc) - uv).ravel()

    n_pts = len(uv)
    sparsity = lil_matrix((2 * n_pts, 6 * (nc + npl)), dtype=int)
    rows = np.arange(n_pts)
    for k in range(6):
        for r in (2 * rows, 2 * rows + 1):
            sparsity[r, 6 * cam_idx + k] = 1
            sparsity[r[~floor], 6 * (nc + pl_idx[~floor]) + k] = 1
    if progress:
        progress(0, 1, "bundle adjustment")
    sol = least_squares(residuals, x0, jac_sparsity=sparsity, method="trf", xtol=1e-10, ftol=1e-10)
    if progress:
        progress(1, 1, "bundle adjustment")
    res = sol.fun.reshape(-1, 2)
    err2 = np.sum(res ** 2, axis=1)
    cp = sol.x[: 6 * nc].reshape(nc, 6)
    calibrated = {}
    for n in cam_names:
        k = ci[n]
        calibrated[n] = Camera(n, intr[n].matrix, intr[n].distortion, rodrigues_to_matrix(cp[k, :3]), cp[k, 3:], intr[n].size)
    placements = {0: np.eye(4)}
    for p in place_ids:
        v = sol.x[6 * (nc + pi[p]): 6 * (nc + pi[p]) + 6]
        placements[p] = _to_T(v[:3], v[3:])
    reports = []
    for n in intr:
        if n in calibrated:
            m = cam_idx == ci[n]
            mine = [o for o in obs if o.camera == n]
            methods = sorted({o.method for o in mine})
            frames = tuple(sorted({f for o in mine for f in o.frames}))
            reports.append(CameraReport(n, True, "+".join(methods), frames, int(m.sum()), float(np.sqrt(err2[m].mean()))))
        else:
            reports.append(CameraReport(n, False, reason=failures[n]))
    return ExtrinsicsResult(
        tuple(calibrated[n] for n in intr if n in calibrated),
        tuple(reports),
        placements,
        float(np.sqrt(err2.mean())),
        int(sol.nfev),
        int(sol.status),
        str(sol.message),
    )
