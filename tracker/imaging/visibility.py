"""Occlusion of contour points by the other parts of the body.

A point P seen from camera centre C is hidden when the segment ``C + s (P - C)``,
``s in [0, 1]``, meets the solid truncated cone of another part (its end caps
included).  In a part's frame the solid is::

    (x/a)² + (y/b)² <= (1 + k z)²,   z1 <= z <= z2

(``1 + k z > 0`` on ``[z1, z2]``, so this is one nappe: a convex solid).  Along
the segment, with ``g = (m1/a, m2/b, 1 + k m3)`` from the camera centre m and
``h = (d1/a, d2/b, k d3)`` from the direction d (both in the part frame), the
cone test is the quadratic ``q(s) = |g + s h|²_(+,+,-) <= 0`` and the caps cut
``s`` to the slab interval.  The segment meets the solid when the minimum of
``q`` over ``[0, 1] ∩ slab`` is negative: the minimum of a quadratic on an
interval is at an end or at its vertex.

Speed: (point, part) pairs are first culled in the image plane: the point's
image must lie in the part's bounding box, projected by the pinhole model (a
central projection maps the box's convex hull inside the hull of its corners'
images, and the segment from the camera centre to the point projects to the
point's image, so the cull is exact for boxes in front of the camera; a point
behind the camera or a part not wholly in front is never culled).  The exact
test then runs on the remaining pairs, one compiled loop over the points
(``tracker.kernels``).

A point inside another part's solid counts as hidden (it is not on the body's
outline).  A point exactly on another part's surface is not (tolerance 1e-9
on ``q``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from capture.camera import Camera, stack_cameras
from tracker.kernels import covered_mask, hidden_mask
from tracker.body.kinematics import Pose
from tracker.body.model import BodyModel

__all__ = ["hidden_points", "covered_rays"]


def hidden_points(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    cam: np.ndarray,
    part: np.ndarray,
    points: np.ndarray,
    *,
    only: np.ndarray | None = None,
) -> np.ndarray:
    """Which points are hidden from their camera by another part.

    Parameters
    ----------
    model : BodyModel
    pose : Pose
    cameras : sequence of Camera, length n_cams
    cam, part : ndarray of int, shape (n,)
        Camera index and own part index of each point (the own part is not an occluder).
    points : ndarray, shape (n, 3)
        World points.
    only : ndarray of bool, shape (n,), optional
        Test only these points; the others are reported not hidden.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    n = points.shape[0]
    test = np.ones(n, dtype=bool) if only is None else np.asarray(only, dtype=bool)
    if n == 0 or not test.any():
        return np.zeros(n, dtype=bool)
    st = stack_cameras(cameras)
    return hidden_mask(model.cones, pose.rotation, pose.translation, st.rotation, st.translation,
                       np.asarray(cam, dtype=np.intp), np.asarray(part, dtype=np.intp),
                       np.ascontiguousarray(points, dtype=float), test)


def covered_rays(model: BodyModel, pose: Pose, cameras: Sequence[Camera], cam: np.ndarray, directions: np.ndarray, *,
                 margin_m: np.ndarray | float = 0.0, range_m: float = 50.0) -> np.ndarray:
    """Which rays from the centres of ``cameras`` meet the body: a pixel's ray meets it exactly when
    the pixel lies on the model's silhouette.

    Parameters
    ----------
    cam : ndarray of int, shape (n,)
        Camera of each ray (index into ``cameras``).
    directions : ndarray, shape (n, 3)
        Unit directions, world.
    margin_m : ndarray (n_cams, n_parts) or float
        Every solid grown by this much (its semi-axes before the taper, and both caps), metres:
        e.g. a tolerance of ``t`` pixels is ``t × depth / focal length`` for a part at that depth.
    range_m : rays are followed this far.

    The (ray, part) pairs are culled by the parts' image boxes (as in ``hidden_points``; a ray
    pointing away from a camera meets nothing), then tested exactly on the segment
    ``[0, range_m]`` of each ray.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    D = np.asarray(directions, dtype=float).reshape(-1, 3)
    cam = np.asarray(cam, dtype=np.intp).reshape(-1)
    if cam.shape[0] != D.shape[0]:
        raise ValueError(f"cam, directions: expected one camera index per ray, got {cam.shape[0]} and {D.shape[0]}")
    hit = np.zeros(D.shape[0], dtype=bool)
    if D.shape[0] == 0:
        return hit
    st = stack_cameras(cameras)
    grow = np.broadcast_to(np.asarray(margin_m, dtype=float), (len(st.rotation), model.n_parts))
    return covered_mask(model.cones, pose.rotation, pose.translation, st.rotation, st.translation, cam,
                        np.ascontiguousarray(D), np.ascontiguousarray(grow), float(range_m))
