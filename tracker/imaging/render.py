"""Rasterise the body model: part-label images, silhouettes and internal edges.

Method.  A truncated elliptical cone with a linear taper is the convex hull
of its two end ellipses, and a pinhole projection maps a convex solid in
front of the camera onto the convex hull of the projected points.  So each
part's image region is the convex hull of the projections of ``n_theta``
points on each of ``n_z`` cross-sections (the two ends plus intermediate
ones, which let the hull follow the curvature that OpenCV lens distortion
adds).  Cross-section polygons are scaled to the ellipse's area, so the
polygonal approximation neither shrinks nor grows the part on average.

Parts are filled with ``cv2.fillConvexPoly`` (sub-pixel, 4 fractional bits;
pixel centres at integer coordinates as in ``capture.camera``) into a label
image in painter's order, far to near by the camera depth of each part's
axis midpoint.  That order is exact for parts that do not interpenetrate
and a good approximation where a limb enters the torso.

Clipping: points less than ``near_m`` in front of the camera are dropped,
so a part crossing the camera plane is drawn from its visible points only
(never happens with a studio ring).  Distortion is applied as the camera
model defines it; far outside the image (beyond the calibrated field) the
OpenCV polynomial is meaningless, so a distorted camera should see the
subject well inside its image.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from capture.camera import Camera
from tracker.body.kinematics import Pose
from tracker.body.model import BodyModel

__all__ = [
    "cone_points",
    "body_points",
    "render_labels",
    "render_label_images",
    "render_silhouettes",
    "internal_edges",
    "fill_convex_hulls",
    "BACKGROUND",
]

#: Label of pixels that no part covers.
BACKGROUND = -1
_SHIFT = 4  # fractional bits for cv2.fillConvexPoly
_LIMIT_PX = 1.0e6  # clamp projected coordinates (int32 with _SHIFT bits)
_INSET_PX = 0.5  # see _shrink
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def cone_points(model: BodyModel, *, n_theta: int = 32, n_z: int = 4) -> np.ndarray:
    """Points on every part's cone surface in its part frame, shape (n_parts, n_z * n_theta, 3).

    Cross-sections at ``n_z`` evenly spaced ``z`` from ``z1`` to ``z2``; each
    is an ``n_theta``-gon whose area equals the ellipse's.
    """
    if n_theta < 8 or n_z < 2:
        raise ValueError(f"cone_points: need n_theta >= 8 and n_z >= 2, got {n_theta}, {n_z}")
    a, b, k, z1, z2 = (model.cones[:, i][:, None, None] for i in range(5))
    s = np.linspace(0.0, 1.0, n_z)[None, :, None]
    z = z1 + (z2 - z1) * s  # (n_parts, n_z, 1)
    theta = np.linspace(0.0, 2 * np.pi, n_theta, endpoint=False)[None, None, :]
    area_scale = np.sqrt(2 * np.pi / (n_theta * np.sin(2 * np.pi / n_theta)))
    r = (1.0 + k * z) * area_scale
    pts = np.stack(np.broadcast_arrays(a * r * np.cos(theta), b * r * np.sin(theta), z), axis=-1)
    return pts.reshape(model.n_parts, n_z * n_theta, 3)


def body_points(model: BodyModel, pose: Pose, *, n_theta: int = 32, n_z: int = 4) -> np.ndarray:
    """The surface points of ``cone_points`` in world coordinates, shape (n_parts, n_z * n_theta, 3)."""
    local = cone_points(model, n_theta=n_theta, n_z=n_z)
    return np.einsum("pij,pmj->pmi", pose.rotation, local) + pose.translation[:, None, :]


def part_centres(model: BodyModel, pose: Pose) -> np.ndarray:
    """World position of each part's axis midpoint, shape (n_parts, 3)."""
    mid = np.zeros((model.n_parts, 3))
    mid[:, 2] = 0.5 * (model.cones[:, 3] + model.cones[:, 4])
    return np.einsum("pij,pj->pi", pose.rotation, mid) + pose.translation


def fill_convex_hulls(
    image: np.ndarray,
    uv: np.ndarray,
    valid: np.ndarray,
    order: Sequence[int],
    values: Sequence,
) -> np.ndarray:
    """Fill the convex hull of each point group into ``image`` in the given order (in place).

    Parameters
    ----------
    image : ndarray, shape (h, w) or (h, w, c)
    uv : ndarray, shape (n_groups, m, 2)
        Pixel coordinates.
    valid : ndarray of bool, shape (n_groups, m)
        Points to use; a group with fewer than 3 valid points is skipped.
    order : sequence of int
        Group indices, first drawn first (painter's order: far to near).
    values : sequence
        ``values[g]`` is the fill value (scalar or colour tuple) of group ``g``.
    """
    uv = np.where(np.isfinite(uv), np.clip(uv, -_LIMIT_PX, _LIMIT_PX), 0.0).astype(np.float32)
    for g in order:
        pts = uv[g][valid[g]]
        if len(pts) < 3:
            continue
        hull = _shrink(cv2.convexHull(pts)[:, 0, :].astype(np.float64), _INSET_PX)
        fixed = np.round(hull * (1 << _SHIFT)).astype(np.int32)
        cv2.fillConvexPoly(image, fixed, values[g], lineType=cv2.LINE_8, shift=_SHIFT)
    return image


def _shrink(hull: np.ndarray, d: float) -> np.ndarray:
    """Offset a convex polygon (n, 2) inward by ``d`` pixels (each edge moves along its normal).

    ``cv2.fillConvexPoly`` also sets every pixel its outline passes through,
    which grows a shape by about half a pixel; insetting the outline by that
    much makes the filled set match "pixel centre inside the shape".
    """
    n = len(hull)
    if n < 3:
        return hull
    e = np.roll(hull, -1, axis=0) - hull  # edge i: v_i -> v_{i+1}
    length = np.linalg.norm(e, axis=1)
    keep = length > 1e-9
    if keep.sum() < 3:
        return hull
    hull, e, length = hull[keep], e[keep], length[keep]
    e = np.roll(hull, -1, axis=0) - hull
    length = np.linalg.norm(e, axis=1)
    normal = np.stack([e[:, 1], -e[:, 0]], axis=1) / length[:, None]
    area2 = np.sum(hull[:, 0] * np.roll(hull[:, 1], -1) - np.roll(hull[:, 0], -1) * hull[:, 1])
    if area2 < 0:  # clockwise in (x right, y down) maths: flip so normals point outward
        normal = -normal
    prev = np.roll(normal, 1, axis=0)  # normal of edge i-1, which ends at v_i
    denom = np.maximum(1.0 + np.sum(prev * normal, axis=1), 0.2)  # cap the miter on sharp corners
    out = hull - d * (prev + normal) / denom[:, None]
    # a polygon thinner than 2d collapses: fall back to its centroid-shrunk copy
    if abs(area2) < 2 * d * length.sum():
        c = hull.mean(axis=0)
        return c + (hull - c) * 0.999
    return out


def render_label_images(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    *,
    n_theta: int = 32,
    n_z: int = 4,
    near_m: float = 0.01,
) -> list[np.ndarray]:
    """Part-label images for several cameras (painter's order by depth; the module docstring).

    Parameters
    ----------
    model : BodyModel
    pose : Pose
    cameras : sequence of Camera
    n_theta, n_z : int
        Points per cross-section and cross-sections per part (``cone_points``).
    near_m : float
        Points nearer than this in front of a camera are dropped, metres.

    Returns
    -------
    list of ndarray, each shape (h, w), int16
        Part index per pixel, ``BACKGROUND`` (-1) where no part is.
    """
    pts = body_points(model, pose, n_theta=n_theta, n_z=n_z)  # (P, M, 3)
    centres = part_centres(model, pose)
    labels_out = []
    values = list(range(model.n_parts))
    for cam in cameras:
        depth = cam.depth(pts)
        uv = cam.project(pts)
        valid = (depth > near_m) & np.all(np.isfinite(uv), axis=-1)
        order = np.argsort(-cam.depth(centres), kind="stable")
        img = np.full((cam.height, cam.width), BACKGROUND, np.int16)
        labels_out.append(fill_convex_hulls(img, uv, valid, order, values))
    return labels_out


def render_labels(model: BodyModel, pose: Pose, camera: Camera, **kwargs) -> np.ndarray:
    """``render_label_images`` for one camera: shape (h, w) int16, part index or -1."""
    return render_label_images(model, pose, [camera], **kwargs)[0]


def render_silhouettes(model: BodyModel, pose: Pose, cameras: Sequence[Camera], **kwargs) -> list[np.ndarray]:
    """Silhouette masks, one per camera, each shape (h, w) uint8 with 255 on the body.

    Parameters
    ----------
    model, pose, cameras, **kwargs
        As ``render_label_images``.

    Returns
    -------
    list of ndarray, each shape (h, w), uint8
    """
    return [np.where(lab >= 0, 255, 0).astype(np.uint8) for lab in render_label_images(model, pose, cameras, **kwargs)]


def internal_edges(labels: np.ndarray) -> np.ndarray:
    """Edges of a label image, shape (h, w) uint8: 255 on the silhouette boundary and between parts.

    A body pixel is an edge pixel when one of its 4-neighbours is background
    or carries a *smaller* part index: silhouette boundaries lie on the body
    side, and a boundary between two parts is one pixel thick (on the side
    of the larger index).  Pixels on the image border are compared with the
    background outside the image.
    """
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ValueError(f"internal_edges: labels must be 2-D (h, w), got shape {lab.shape}")
    lab16 = lab.astype(np.int16, copy=False)
    # the smallest label among each pixel and its 4-neighbours (background outside the image)
    smallest = cv2.erode(lab16, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=BACKGROUND)
    return np.where((smallest < lab16) & (lab16 >= 0), 255, 0).astype(np.uint8)
