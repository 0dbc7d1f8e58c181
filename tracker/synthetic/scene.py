"""A synthetic studio: a ring of cameras, a textured room and a light.

Everything here is pure: arrays in, arrays out, randomness from an explicit
seed.  The room is a floor (z = 0) inside a vertical cylindrical wall of
radius ``wall_radius_m`` centred on the world origin; both carry a seeded
procedural texture (smooth value noise plus tiles on the floor and stripes on
the wall) so that a background model has something to learn and a
segmenter cannot win by thresholding a flat colour.

``render_background(camera, texture)`` ray-casts every pixel centre through
the camera model (OpenCV distortion inverted with ``cv2.undistortPoints``)
and looks up the texture of the surface hit, so the background seen by the
several cameras is one consistent 3-D scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from capture.camera import Camera

__all__ = ["ring_cameras", "fit_ring_cameras", "RoomTexture", "make_room_texture", "render_background", "pixel_rays"]


def ring_cameras(
    n: int,
    *,
    size: tuple[int, int] = (800, 600),
    radius_m: float = 4.0,
    height_m: float = 1.5,
    target=(0.0, 0.0, 1.0),
    fov_deg: float = 60.0,
    distortion=(0.0, 0.0, 0.0, 0.0, 0.0),
    start_deg: float = 0.0,
) -> list[Camera]:
    """``n`` cameras evenly spaced on a horizontal circle, all looking at ``target``.

    Camera ``i`` (named ``cam{i}``) sits at azimuth ``start_deg + 360 i / n`` degrees (0 = on the
    +X axis, so camera 0 sees the front of a subject at Φ = 0).  60° at 4 m with a 4:3 image sees
    about ±2.3 m horizontally and ±1.7 m vertically around the target: a standing person with a
    metre of margin for motion.

    Parameters
    ----------
    n : int
    size : (int, int)
        (w, h), pixels.
    radius_m, height_m : float
        Distance from the vertical through ``target`` and height above the floor, metres.
    target : (float, float, float)
        World point every camera looks at, metres.
    fov_deg : float
        Horizontal field of view, degrees.
    distortion : sequence of float
        OpenCV distortion coefficients.
    start_deg : float
        Azimuth of camera 0, degrees.

    Returns
    -------
    list of Camera
    """
    if n < 1:
        raise ValueError(f"ring_cameras: n must be >= 1, got {n}")
    if radius_m <= 0:
        raise ValueError(f"ring_cameras: radius_m must be positive, got {radius_m}")
    if not 1.0 < fov_deg < 179.0:
        raise ValueError(f"ring_cameras: fov_deg must be in (1, 179), got {fov_deg}")
    target = np.asarray(target, dtype=float)
    cams = []
    for i in range(n):
        az = np.radians(start_deg + 360.0 * i / n)
        eye = np.array([target[0] + radius_m * np.cos(az), target[1] + radius_m * np.sin(az), height_m])
        cams.append(Camera.look_at(f"cam{i}", eye, target, size=size, fov_deg=fov_deg, distortion=distortion))
    return cams


def fit_ring_cameras(
    points: np.ndarray,
    n: int,
    *,
    size: tuple[int, int] = (800, 600),
    radius_m: float = 4.0,
    height_m: float = 1.5,
    clearance_m: float = 2.0,
    margin: float = 0.05,
    fov_range_deg: tuple[float, float] = (40.0, 110.0),
) -> list[Camera]:
    """A ring (``ring_cameras``) that keeps every given point in every image.

    Parameters
    ----------
    points : ndarray, shape (..., 3)
        World points that must be seen (e.g. the body's surface over a clip).
    radius_m : float
        Minimum ring radius; it grows to keep ``clearance_m`` between each
        camera and the farthest horizontal excursion of the points.
    margin : float
        Fraction of the image width/height left free on each side.

    The target is the centre of the points' bounding box; the horizontal
    field of view is the smallest (1° steps in ``fov_range_deg``) that fits;
    the widest is returned if none does.

    Returns
    -------
    list of Camera
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    if pts.size == 0 or not np.all(np.isfinite(pts)):
        raise ValueError("fit_ring_cameras: points must be a non-empty finite (..., 3) array")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    target = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])])
    reach = np.hypot(pts[:, 0] - target[0], pts[:, 1] - target[1]).max()
    radius = max(radius_m, reach + clearance_m)
    w, h = size
    cams = None
    for fov in np.arange(fov_range_deg[0], fov_range_deg[1] + 0.5, 1.0):
        cams = ring_cameras(n, size=size, radius_m=radius, height_m=height_m, target=target, fov_deg=float(fov))
        ok = True
        for cam in cams:
            uv = cam.project(pts)
            if not (
                np.all(cam.depth(pts) > 0.1)
                and np.all((uv[:, 0] >= margin * w) & (uv[:, 0] <= (1 - margin) * w))
                and np.all((uv[:, 1] >= margin * h) & (uv[:, 1] <= (1 - margin) * h))
            ):
                ok = False
                break
        if ok:
            break
    return cams


@dataclass(frozen=True, eq=False)
class RoomTexture:
    """Procedural room textures.

    Attributes
    ----------
    floor : ndarray, shape (n, n, 3) uint8
        Floor colour over ``[-extent, extent]²`` metres (rows = y, cols = x).
    wall : ndarray, shape (m, n_az, 3) uint8
        Wall colour over azimuth [-π, π) (cols) and height [0, wall_height_m] (rows, bottom first).
    extent_m, wall_radius_m, wall_height_m : float
    """

    floor: np.ndarray
    wall: np.ndarray
    extent_m: float
    wall_radius_m: float
    wall_height_m: float


def _value_noise(
    rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int], *, wrap_columns: bool = False
) -> np.ndarray:
    """Smooth noise in [0, 1], shape ``shape``: a random ``cells`` grid, bicubically upsampled.

    ``wrap_columns`` makes the last column equal the first (no seam where a
    wall texture closes on itself)."""
    coarse = rng.random((cells[0] + 1, cells[1] + 1)).astype(np.float32)
    if wrap_columns:
        coarse[:, -1] = coarse[:, 0]
    return np.clip(cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC), 0.0, 1.0)


def make_room_texture(
    seed: int = 0,
    *,
    extent_m: float = 8.0,
    wall_radius_m: float = 7.0,
    wall_height_m: float = 3.0,
    resolution_px_per_m: int = 64,
) -> RoomTexture:
    """A seeded floor and wall texture (deterministic for a given seed).

    Parameters
    ----------
    seed : int
    extent_m : float
        Half-size of the square floor, metres.
    wall_radius_m, wall_height_m : float
        The cylindrical wall, metres.
    resolution_px_per_m : int
        Texture pixels per metre.

    Returns
    -------
    RoomTexture
    """
    rng = np.random.default_rng(seed)
    n = int(2 * extent_m * resolution_px_per_m)
    base_floor = rng.uniform(90, 160, 3)
    noise = _value_noise(rng, (n, n), (24, 24)) * 0.6 + _value_noise(rng, (n, n), (160, 160)) * 0.4
    ij = np.arange(n) / resolution_px_per_m
    tiles = ((np.floor(ij[:, None] / 0.5) + np.floor(ij[None, :] / 0.5)) % 2) * 2 - 1  # 0.5 m tiles
    floor = base_floor[None, None, :] * (0.75 + 0.35 * noise[..., None]) + 12.0 * tiles[..., None]
    m = int(wall_height_m * resolution_px_per_m)
    n_az = int(2 * np.pi * wall_radius_m * resolution_px_per_m / 2)
    base_wall = rng.uniform(120, 200, 3)
    wnoise = _value_noise(rng, (m, n_az), (12, 64), wrap_columns=True)
    stripes = np.sin(np.linspace(0, 2 * np.pi * 40, n_az, endpoint=False))[None, :]
    wall = base_wall[None, None, :] * (0.7 + 0.4 * wnoise[..., None]) + 10.0 * stripes[..., None]
    return RoomTexture(
        floor=np.clip(floor, 0, 255).astype(np.uint8),
        wall=np.clip(wall, 0, 255).astype(np.uint8),
        extent_m=float(extent_m),
        wall_radius_m=float(wall_radius_m),
        wall_height_m=float(wall_height_m),
    )


def pixel_rays(camera: Camera) -> np.ndarray:
    """Unit world directions of the rays through every pixel centre.

    Distortion is inverted (``Camera.rays``), so the ray through pixel (u, v) projects back to it.

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    ndarray, shape (h, w, 3)
    """
    w, h = camera.size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    return camera.rays(np.stack([u.ravel(), v.ravel()], axis=-1)).reshape(h, w, 3)


def render_background(camera: Camera, texture: RoomTexture, *, with_floor_mask: bool = False):
    """The empty room seen by ``camera``.

    Every pixel's ray hits the floor (z = 0) or the cylindrical wall; rays that hit neither (above
    the wall) see a plain ceiling grey.

    Parameters
    ----------
    camera : Camera
    texture : RoomTexture
    with_floor_mask : bool
        Also return where the floor is seen.

    Returns
    -------
    image : ndarray, shape (h, w, 3), uint8
        BGR.
    floor : ndarray of bool, shape (h, w)
        Only with ``with_floor_mask``.
    """
    rays = pixel_rays(camera)
    c = camera.center
    h, w = rays.shape[:2]
    d = rays.reshape(-1, 3)
    # wall: |c_xy + t d_xy| = R, the positive root
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (c[0] * d[:, 0] + c[1] * d[:, 1])
    cc = c[0] ** 2 + c[1] ** 2 - texture.wall_radius_m**2
    with np.errstate(divide="ignore", invalid="ignore"):
        t_wall = (-b + np.sqrt(np.maximum(b * b - 4 * a * cc, 0.0))) / (2 * a)
        t_floor = np.where(d[:, 2] < -1e-9, -c[2] / d[:, 2], np.inf)
    hit_floor = t_floor < t_wall
    out = np.full((h * w, 3), 170, np.uint8)
    # floor lookup
    P = c + t_floor[hit_floor, None] * d[hit_floor]
    res = texture.floor.shape[0] / (2 * texture.extent_m)
    map_x = ((P[:, 0] + texture.extent_m) * res).astype(np.float32)
    map_y = ((P[:, 1] + texture.extent_m) * res).astype(np.float32)
    out[hit_floor] = _lookup(texture.floor, map_x, map_y)
    # wall lookup
    wall = ~hit_floor & np.isfinite(t_wall)
    Q = c + t_wall[wall, None] * d[wall]
    az = np.arctan2(Q[:, 1], Q[:, 0])
    m, n_az = texture.wall.shape[:2]
    wx = ((az + np.pi) / (2 * np.pi) * n_az).astype(np.float32)
    wy = ((1.0 - Q[:, 2] / texture.wall_height_m) * m).astype(np.float32)
    below = Q[:, 2] <= texture.wall_height_m
    colour = _lookup(texture.wall, wx, wy)
    colour[~below] = 170
    out[wall] = colour
    if with_floor_mask:
        return out.reshape(h, w, 3), hit_floor.reshape(h, w)
    return out.reshape(h, w, 3)


def _lookup(tex: np.ndarray, map_x: np.ndarray, map_y: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup at float pixel coordinates (n,), returns (n, 3) uint8."""
    if map_x.size == 0:
        return np.zeros((0, 3), np.uint8)
    n = map_x.size
    cols = 1024  # cv2.remap wants maps narrower than SHRT_MAX: lay the n lookups out as rows
    pad = (-n) % cols
    mx = np.concatenate([map_x, np.zeros(pad, np.float32)]).reshape(-1, cols)
    my = np.concatenate([map_y, np.zeros(pad, np.float32)]).reshape(-1, cols)
    out = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return out.reshape(-1, 3)[:n]
