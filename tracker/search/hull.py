"""Hierarchical (coarse-to-fine) visual hull from calibrated silhouettes (Caillette & Howard, BMVC'04 §3.3).

A coarse grid of cubic voxels (``coarse`` cells along the longest side of the bounds) is
classified against every silhouette at once; only the voxels the silhouettes cannot decide are
split into 8 and classified again, down to ``min_voxel_m``.  A voxel's footprint in a view is the
pixel box enclosing its 8 projected corners (grown to whole pixels, so the tests are
conservative); with an integral image of the mask the box's foreground count is 4 lookups:

- count == 0 in any view (or the box is off the image / behind the camera): **empty**;
- count == box area in every view: **full** (kept at its size, not split);
- otherwise: split into 8.

The finest level is decided by the centre alone (kept iff it projects on the silhouette in
every view): the standard sampled visual hull, at 1/8 of the cost of box tests.  Everything is
vectorised per level over all voxels, camera by camera (a cube found empty is dropped from the
remaining views).  The result is a list of cubes
of mixed sizes (``VoxelHull``) with volume-weighted moments for initialisation (centroid,
principal axes, height) and a point cloud for clients.  ``render_hull`` rasterises a hull back
into a camera (ray/box slab test per pixel of each voxel's footprint), for consistency checks.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from capture.camera import Camera

__all__ = ["VoxelHull", "visual_hull", "centres_inside", "common_view_bounds", "render_hull", "silhouette_iou",
           "project_with_depth"]

# the 8 corners of the unit cube, (8, 3)
_CORNERS = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=float)
# the 8 children's lower-corner offsets in units of the child size, (8, 3)
_CHILDREN = _CORNERS


@dataclass(frozen=True, eq=False)
class VoxelHull:
    """A visual hull as cubes of mixed sizes (world frame, metres).

    Attributes
    ----------
    centres : ndarray, shape (n, 3)
        Voxel centres.
    sizes : ndarray, shape (n,)
        Voxel edge lengths.
    full : ndarray of bool, shape (n,)
        True for voxels proven inside every silhouette; False for finest-level voxels kept
        because their centre projects inside every silhouette (the hull's surface layer).
    bounds : ndarray, shape (2, 3)
        The reconstructed box ``[lower, upper]`` (the grid, cube-aligned).
    min_voxel_m : float
        Finest voxel size.
    """

    centres: np.ndarray
    sizes: np.ndarray
    full: np.ndarray
    bounds: np.ndarray
    min_voxel_m: float

    @property
    def n_voxels(self) -> int:
        return len(self.sizes)

    @property
    def empty(self) -> bool:
        return self.n_voxels == 0

    @property
    def volumes(self) -> np.ndarray:
        """Voxel volumes, shape (n,), m³."""
        return self.sizes**3

    @property
    def volume(self) -> float:
        return float(self.volumes.sum())

    def _require(self) -> None:
        if self.empty:
            raise ValueError("the visual hull is empty (no voxel inside every silhouette)")

    def centroid(self) -> np.ndarray:
        """Volume-weighted centre of mass, shape (3,)."""
        self._require()
        w = self.volumes
        return (self.centres * w[:, None]).sum(0) / w.sum()

    def covariance(self) -> np.ndarray:
        """Volume-weighted second moment about the centroid, shape (3, 3) (includes each cube's own spread)."""
        self._require()
        w = self.volumes / self.volumes.sum()
        d = self.centres - self.centroid()
        own = (w * self.sizes**2 / 12.0).sum() * np.eye(3)  # a cube's inertia about its centre
        return (d * w[:, None]).T @ d + own

    def principal_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues (3,) descending and unit axes as columns (3, 3) of ``covariance``."""
        vals, vecs = np.linalg.eigh(self.covariance())
        order = np.argsort(vals)[::-1]
        return vals[order], vecs[:, order]

    def floor_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Principal axes of the horizontal (x, y) spread: eigenvalues (2,) descending, axes (2, 2) as columns."""
        vals, vecs = np.linalg.eigh(self.covariance()[:2, :2])
        return vals[::-1], vecs[:, ::-1]

    def extent(self) -> np.ndarray:
        """Tight box of the voxels' cubes, shape (2, 3): ``[lower, upper]``."""
        self._require()
        h = 0.5 * self.sizes[:, None]
        return np.stack([(self.centres - h).min(0), (self.centres + h).max(0)])

    def height(self) -> float:
        """Vertical extent of the hull (top minus bottom of its cubes), metres."""
        lo, hi = self.extent()
        return float(hi[2] - lo[2])

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether world points lie in a voxel of the hull.

        Parameters
        ----------
        points : ndarray, shape (m, 3)
            World metres.

        Returns
        -------
        ndarray of bool, shape (m,)
        """
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.empty:
            return np.zeros(len(P), bool)
        # finest-cell keys of every voxel, then a sorted lookup of the points' cells
        cells = np.floor((self.points() - self.bounds[0]) / self.min_voxel_m).astype(np.int64)
        dims = np.ceil((self.bounds[1] - self.bounds[0]) / self.min_voxel_m).astype(np.int64) + 1
        keys = np.unique(np.ravel_multi_index(cells.T, dims, mode="clip"))
        q = np.floor((P - self.bounds[0]) / self.min_voxel_m).astype(np.int64)
        inside = np.all((q >= 0) & (q < dims), axis=1)
        qk = np.ravel_multi_index(np.clip(q, 0, dims - 1).T, dims)
        pos = np.clip(np.searchsorted(keys, qk), 0, len(keys) - 1)
        return inside & (keys[pos] == qk)

    def largest_component(self) -> "VoxelHull":
        """The hull restricted to its largest 26-connected piece by volume.

        Drops phantom blobs that segmentation noise leaves where the views happen to agree.

        Returns
        -------
        VoxelHull
        """
        if self.empty:
            return self
        from scipy import ndimage

        lo = self.extent()[0]
        cells = np.floor((self.points() - lo) / self.min_voxel_m).astype(np.int64)
        grid = np.zeros(cells.max(0) + 1, bool)
        grid[tuple(cells.T)] = True
        labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
        if n <= 1:
            return self
        volume = np.bincount(labels[tuple(cells.T)], minlength=n + 1)
        keep = np.argmax(volume[1:]) + 1
        own = np.floor((self.centres - lo) / self.min_voxel_m).astype(np.int64)
        own = np.clip(own, 0, np.array(grid.shape) - 1)
        sel = labels[tuple(own.T)] == keep
        return VoxelHull(self.centres[sel], self.sizes[sel], self.full[sel], self.bounds, self.min_voxel_m)

    def points(self, *, spacing_m: float | None = None) -> np.ndarray:
        """A point cloud filling the hull: each cube split into cells of ``spacing_m``, their centres.

        Parameters
        ----------
        spacing_m : float, optional
            Cell size, metres (default the finest voxel size).

        Returns
        -------
        ndarray, shape (m, 3)
        """
        s = self.min_voxel_m if spacing_m is None else float(spacing_m)
        if s <= 0:
            raise ValueError(f"spacing_m must be > 0, got {spacing_m}")
        out = []
        for size in np.unique(self.sizes):
            sel = self.sizes == size
            n = max(1, int(round(size / s)))
            g = (np.arange(n) + 0.5) / n - 0.5
            sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) * size
            out.append((self.centres[sel][:, None, :] + sub[None]).reshape(-1, 3))
        return np.concatenate(out) if out else np.zeros((0, 3))


_BOUNDS_CACHE: dict = {}


def common_view_bounds(cameras: Sequence[Camera], *, z_range=(0.0, 2.5), step_m: float = 0.2,
                       margin_m: float = 0.2) -> np.ndarray:
    """Box ``(2, 3)`` around the floor region every camera sees (heights in ``z_range``).

    Samples a grid over the cameras' horizontal footprint (their centres' box grown by half its
    size) and keeps points in front of and inside every image.  The box depends on the
    calibration alone and is cached per camera set (paid once, not on every hull of a recovery;
    its cost: docs/tuning.md, "Search").

    Parameters
    ----------
    cameras : sequence of Camera
    z_range : (float, float)
        Heights of the box, metres.
    step_m : float
        Spacing of the sampled floor grid, metres.
    margin_m : float
        Growth of the box around the points kept, metres.

    Returns
    -------
    ndarray, shape (2, 3)
        ``[lower, upper]`` corners, world metres.
    """
    key = (tuple((c.matrix.tobytes(), c.distortion.tobytes(), c.rotation.tobytes(), c.translation.tobytes(), c.size)
                 for c in cameras), tuple(float(z) for z in z_range), float(step_m), float(margin_m))
    if key not in _BOUNDS_CACHE:
        if len(_BOUNDS_CACHE) >= 16:
            _BOUNDS_CACHE.pop(next(iter(_BOUNDS_CACHE)))
        _BOUNDS_CACHE[key] = _common_view_bounds(cameras, z_range, step_m, margin_m)
    return _BOUNDS_CACHE[key].copy()


def _common_view_bounds(cameras: Sequence[Camera], z_range, step_m: float, margin_m: float) -> np.ndarray:
    centres = np.array([c.center for c in cameras])
    lo, hi = centres[:, :2].min(0), centres[:, :2].max(0)
    pad = 0.5 * (hi - lo) + 1.0
    xs = np.arange(lo[0] - pad[0], hi[0] + pad[0] + step_m, step_m)
    ys = np.arange(lo[1] - pad[1], hi[1] + pad[1] + step_m, step_m)
    zs = np.arange(z_range[0], z_range[1] + 0.5 * step_m, step_m)
    P = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), -1).reshape(-1, 3)
    seen = np.ones(len(P), bool)
    for cam in cameras:
        uv, z = project_with_depth(cam, P)
        seen &= (z > 1e-3) & cam.in_image(np.nan_to_num(uv, nan=-1.0))
    if not seen.any():
        raise ValueError("the cameras share no common view between z = %.2f and %.2f m" % tuple(z_range))
    Q = P[seen]
    lo, hi = Q.min(0) - margin_m, Q.max(0) + margin_m
    lo[2] = max(lo[2], z_range[0])  # nothing below the floor
    return np.stack([lo, hi])


def _check_inputs(cameras, silhouettes) -> list[np.ndarray]:
    if len(cameras) == 0:
        raise ValueError("visual_hull needs at least one camera")
    if len(silhouettes) != len(cameras):
        raise ValueError(f"silhouettes: got {len(silhouettes)} masks for {len(cameras)} cameras")
    masks = []
    for cam, m in zip(cameras, silhouettes):
        m = np.asarray(m)
        if m.shape != (cam.height, cam.width):
            raise ValueError(f"silhouettes[{cam.name!r}]: shape {m.shape} != camera size (h, w) = "
                             f"{(cam.height, cam.width)}")
        masks.append(cv2.threshold(m, 0, 1, cv2.THRESH_BINARY)[1] if m.dtype == np.uint8 else (m > 0).astype(np.uint8))
    return masks


def project_with_depth(cam: Camera, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (n, 2) and depths (n,) of world points X (n, 3); one matrix product without distortion."""
    if np.any(cam.distortion != 0):
        return cam.project(X), cam.depth(X)
    x = X @ cam.projection_matrix[:, :3].T + cam.projection_matrix[:, 3]
    z = x[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        return x[:, :2] / z[:, None], z


def _classify(lower: np.ndarray, size: float, cameras, integrals, tolerance: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Classify cubes ``lower`` (n, 3) of edge ``size``: returns (empty (n,), full (n,)) bool.

    Empty: wholly outside more than ``tolerance`` silhouettes; full: not wholly inside at most
    ``tolerance`` of them.  Cameras are taken in turn and a cube found empty is dropped.
    """
    n = len(lower)
    n_out = np.zeros(n, int)
    n_partial = np.zeros(n, int)
    active = np.arange(n)
    for cam, ii in zip(cameras, integrals):
        if active.size == 0:
            break
        h, w = cam.height, cam.width
        m = len(active)
        if np.any(cam.distortion != 0):
            corners = (lower[active][:, None, :] + size * _CORNERS[None]).reshape(-1, 3)
            uv, z = project_with_depth(cam, corners)
            u, v, z = uv[:, 0].reshape(m, 8), uv[:, 1].reshape(m, 8), z.reshape(m, 8)
        else:  # homogeneous image points are affine in the corner: project once, add 8 offsets
            P = cam.projection_matrix
            xh = (lower[active] @ P[:, :3].T + P[:, 3])[:, None, :] + size * (_CORNERS @ P[:, :3].T)[None]
            z = xh[..., 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                inv = 1.0 / z
            u, v = xh[..., 0] * inv, xh[..., 1] * inv
        front = z > 1e-6
        all_front, any_front = front.all(1), front.any(1)
        if not all_front.all():
            u, v = np.where(front, u, np.nan), np.where(front, v, np.nan)
            with warnings.catch_warnings():  # all-NaN rows: cubes wholly behind the camera
                warnings.simplefilter("ignore", RuntimeWarning)
                u0, u1 = np.nanmin(u, 1), np.nanmax(u, 1)
                v0, v1 = np.nanmin(v, 1), np.nanmax(v, 1)
            u0, u1, v0, v1 = (np.nan_to_num(a, nan=-1.0) for a in (u0, u1, v0, v1))
        else:
            u0, u1, v0, v1 = u.min(1), u.max(1), v.min(1), v.max(1)
        u0, v0, u1, v1 = np.floor(u0), np.floor(v0), np.ceil(u1), np.ceil(v1)
        inside_img = all_front & (u0 >= 0) & (v0 >= 0) & (u1 <= w - 1) & (v1 <= h - 1)
        # clipped pixel box [c0, c1) x [r0, r1) in integral-image indices
        c0 = np.clip(u0, 0, w).astype(np.intp)
        c1 = np.clip(u1 + 1, 0, w).astype(np.intp)
        r0 = np.clip(v0, 0, h).astype(np.intp)
        r1 = np.clip(v1 + 1, 0, h).astype(np.intp)
        count = ii[r1, c1] - ii[r0, c1] - ii[r1, c0] + ii[r0, c0]
        area = (c1 - c0) * (r1 - r0)
        # wholly behind the camera or off the image: empty; partly behind: undecided
        out = ~any_front | (area <= 0) | (all_front & (count == 0))
        n_out[active] += out
        n_partial[active] += ~(inside_img & (count == area))
        active = active[n_out[active] <= tolerance]
    empty = n_out > tolerance
    return empty, (n_partial <= tolerance) & ~empty


def centres_inside(centres: np.ndarray, cameras, masks, tolerance: int = 0) -> np.ndarray:
    """Whether points (n, 3) project onto the silhouette in all but ``tolerance`` views, (n,) bool."""
    misses = np.zeros(len(centres), int)
    for cam, m in zip(cameras, masks):
        idx = np.flatnonzero(misses <= tolerance)
        if idx.size == 0:
            break
        uv, z = project_with_depth(cam, centres[idx])
        uv = np.rint(np.nan_to_num(uv, nan=-1.0, posinf=-1.0, neginf=-1.0)).astype(np.int64)
        inside = (z > 1e-6) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] < cam.height)
        hit = np.zeros(idx.size, bool)
        hit[inside] = m[uv[inside, 1], uv[inside, 0]] > 0
        misses[idx] += ~hit
    return misses <= tolerance


def visual_hull(
    cameras: Sequence[Camera],
    silhouettes: Sequence[np.ndarray],
    *,
    bounds=None,
    min_voxel_m: float = 0.015,
    coarse: int = 16,
    tolerance: int = 0,
) -> VoxelHull:
    """Coarse-to-fine visual hull.

    Parameters
    ----------
    cameras : sequence of Camera
    silhouettes : sequence of ndarray, each shape (h, w) of its camera
        Masks, non-zero = body.
    bounds : array_like, shape (2, 3), optional
        Box ``[lower, upper]`` to reconstruct in (world, metres); default
        ``common_view_bounds(cameras)``.
    min_voxel_m : float
        Finest voxel edge length.
    coarse : int
        Cells of the first grid along the longest side of ``bounds`` (the grid is grown so that
        the finest size is exactly ``min_voxel_m``).
    tolerance : int
        Views a point may fall outside of and still belong to the hull (0: the strict visual
        hull; 1 keeps a limb that one segmentation missed, at the price of a fatter hull).

    Returns
    -------
    VoxelHull
    """
    masks = _check_inputs(cameras, silhouettes)
    if not (min_voxel_m > 0 and np.isfinite(min_voxel_m)):
        raise ValueError(f"min_voxel_m must be > 0, got {min_voxel_m}")
    if int(coarse) < 1:
        raise ValueError(f"coarse must be >= 1, got {coarse}")
    if not 0 <= int(tolerance) < len(cameras):
        raise ValueError(f"tolerance must be in [0, {len(cameras) - 1}] for {len(cameras)} cameras, got {tolerance}")
    box = common_view_bounds(cameras) if bounds is None else np.asarray(bounds, dtype=float).reshape(2, 3)
    if not np.all(box[1] > box[0]):
        raise ValueError(f"bounds must be [lower, upper] with upper > lower, got {box.tolist()}")
    span = float((box[1] - box[0]).max())
    levels = max(0, int(np.ceil(np.log2(span / (int(coarse) * min_voxel_m)))))
    size = min_voxel_m * 2.0**levels
    counts = np.maximum(1, np.ceil((box[1] - box[0]) / size - 1e-9).astype(int))
    origin = box[0].copy()  # grid anchored at the lower corner (the floor stays a voxel face)
    idx = np.stack(np.meshgrid(*(np.arange(c) for c in counts), indexing="ij"), -1).reshape(-1, 3)
    lower = origin + idx * size
    integrals = [cv2.integral(m, sdepth=cv2.CV_32S) for m in masks]  # (h+1, w+1) counts; int32 holds any image
    kept_c, kept_s, kept_f = [], [], []
    for level in range(levels + 1):
        if len(lower) == 0:
            break
        if level == levels:  # finest level: a cube is kept when its centre is on every silhouette
            centre = lower + 0.5 * size
            on = centres_inside(centre, cameras, masks, int(tolerance))
            kept_c.append(centre[on])
            kept_s.append(np.full(int(on.sum()), size))
            kept_f.append(np.zeros(int(on.sum()), bool))
            break
        empty, full = _classify(lower, size, cameras, integrals, int(tolerance))
        kept_c.append(lower[full] + 0.5 * size)
        kept_s.append(np.full(int(full.sum()), size))
        kept_f.append(np.ones(int(full.sum()), bool))
        todo = lower[~empty & ~full]
        size *= 0.5
        lower = (todo[:, None, :] + size * _CHILDREN[None]).reshape(-1, 3)
    centres = np.concatenate(kept_c) if kept_c else np.zeros((0, 3))
    sizes = np.concatenate(kept_s) if kept_s else np.zeros(0)
    full = np.concatenate(kept_f) if kept_f else np.zeros(0, bool)
    grid = np.stack([origin, origin + counts * min_voxel_m * 2.0**levels])
    return VoxelHull(centres, sizes, full, grid, float(min_voxel_m))


def render_hull(hull: VoxelHull, camera: Camera, *, chunk_pairs: int = 250_000) -> np.ndarray:
    """Rasterise the hull into a camera: where a pixel's ray meets a voxel.

    Each voxel's footprint box is enumerated (ragged, vectorised) and every pixel centre's ray is
    tested against the cube (slab test), so the result is exact up to pixel sampling.  Voxels go
    largest first in chunks, and pixels already set are not tested again.

    Parameters
    ----------
    hull : VoxelHull
    camera : Camera
    chunk_pairs : int
        About this many (pixel, voxel) pairs per chunk (memory bound).

    Returns
    -------
    ndarray, shape (h, w), uint8
        255 on the hull, 0 elsewhere.
    """
    h, w = camera.height, camera.width
    out = np.zeros((h, w), np.uint8)
    if hull.empty:
        return out
    order = np.argsort(-hull.sizes, kind="stable")
    lo = hull.centres[order] - 0.5 * hull.sizes[order, None]
    hi = hull.centres[order] + 0.5 * hull.sizes[order, None]
    corners = (lo[:, None, :] + hull.sizes[order, None, None] * _CORNERS[None]).reshape(-1, 3)
    uv, z = project_with_depth(camera, corners)
    front = (z > 1e-6).reshape(-1, 8).all(1)
    uv = np.nan_to_num(uv, nan=0.0, posinf=0.0, neginf=0.0).reshape(-1, 8, 2)
    c0 = np.clip(np.floor(uv[..., 0].min(1)), 0, w).astype(np.intp)
    c1 = np.clip(np.ceil(uv[..., 0].max(1)) + 1, 0, w).astype(np.intp)
    r0 = np.clip(np.floor(uv[..., 1].min(1)), 0, h).astype(np.intp)
    r1 = np.clip(np.ceil(uv[..., 1].max(1)) + 1, 0, h).astype(np.intp)
    bw, bh = np.maximum(c1 - c0, 0) * front, np.maximum(r1 - r0, 0) * front
    n_pix = bw * bh
    C = camera.center
    if np.any(camera.distortion != 0):
        cols, rows = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
        table = camera.rays(np.column_stack([cols.ravel(), rows.ravel()]))  # (h*w, 3)
        rays = lambda col, row: table[row * w + col]  # noqa: E731
    else:  # the ray direction is affine in the pixel: R^T K^-1 (u, v, 1)
        A = camera.rotation.T @ np.linalg.inv(camera.matrix)
        rays = lambda col, row: col[:, None] * A[:, 0] + row[:, None] * A[:, 1] + A[:, 2]  # noqa: E731
    flat = out.ravel()
    cum = np.cumsum(n_pix)
    start = 0
    while start < len(n_pix):
        base = cum[start - 1] if start else 0
        stop = min(len(n_pix), max(start + 1, int(np.searchsorted(cum, base + chunk_pairs, side="right"))))
        sel = np.arange(start, stop)
        start = stop
        counts = n_pix[sel]
        if counts.sum() == 0:
            continue
        vox = np.repeat(sel, counts)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        col = c0[vox] + k % bw[vox]
        row = r0[vox] + k // bw[vox]
        todo = flat[row * w + col] == 0
        vox, col, row = vox[todo], col[todo], row[todo]
        d = rays(col, row)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / d
            t1 = (lo[vox] - C) * inv
            t2 = (hi[vox] - C) * inv
        t1 = np.where(np.isnan(t1), -np.inf, t1)
        t2 = np.where(np.isnan(t2), np.inf, t2)
        tmin = np.minimum(t1, t2).max(1)
        tmax = np.maximum(t1, t2).min(1)
        hit = tmax >= np.maximum(tmin, 0.0)
        flat[row[hit] * w + col[hit]] = 255
    return out


def silhouette_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two masks (non-zero = set).

    Parameters
    ----------
    a, b : ndarray, shape (h, w)

    Returns
    -------
    float
        1.0 when both are empty.
    """
    a, b = np.asarray(a) > 0, np.asarray(b) > 0
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union
