"""Where the body can be in each camera: image rectangles from a (predicted) pose.

Segmentation only needs to look where the body can be.  Given the tracker's prediction for the
next frame (``tracker.fitting.tracking.Tracker.predict``), each part's solid is enclosed in its bounding
box in the part frame (the taper's largest cross-section, both caps), grown by ``margin_m`` for
the prediction's error; the eight corners of every part's box are projected with the camera
model (distortion included) and the rectangle around all of them, grown by ``margin_px``, is the
region of interest of that camera.  A central projection maps a box in front of the camera
inside the convex hull of its corners' images, so without distortion the rectangle holds the
whole predicted silhouette grown by the margins; with lens distortion ``margin_px`` also covers
the (small) bulge of the distorted edges between corners.

The margins must cover the prediction's error: ``segment_frame`` crops the distance images to
the rectangle, so a contour point the fit moves outside it sees the truncation distance
(docs/performance.md has the measured figures).  A fixed ``margin_m`` must cover the fastest
motion; :func:`motion_margins` sizes each part's margin from its own predicted motion instead
(a still torso gets a small one, a swinging forearm a large one).

The rectangle is ``(x0, y0, x1, y1)``, half-open, clipped to the image: what
``segmentation.pipeline.segment_frame(..., roi=...)`` takes.  ``None`` means "the whole frame":
a part reaching behind (or into) the camera plane, or a pose that is not finite.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from capture.camera import Camera, project_many, stack_cameras
from tracker.body.kinematics import Pose, forward
from tracker.body.model import BodyModel

__all__ = ["pose_rois", "part_box_corners", "motion_margins"]

_CORNERS = np.array(np.meshgrid([-1, 1], [-1, 1], [0, 1], indexing="ij")).reshape(3, 8).T  # (8, 3)
_MIN_DEPTH_M = 0.05  # a corner closer to the camera plane than this: the whole frame


def part_box_corners(model: BodyModel, pose: Pose, *, margin_m=0.0) -> np.ndarray:
    """World corners of every part's bounding box grown by ``margin_m`` (metres: one value, or one
    per part, shape (n_parts,)), shape (n_parts * 8, 3)."""
    a, b, k, z1, z2 = (model.cones[:, j] for j in range(5))
    s = np.maximum(1.0 + k * z1, 1.0 + k * z2)  # the largest cross-section's scale
    local = np.empty((model.n_parts, 8, 3))
    local[..., 0] = (a * s + margin_m)[:, None] * _CORNERS[:, 0]
    local[..., 1] = (b * s + margin_m)[:, None] * _CORNERS[:, 1]
    local[..., 2] = np.where(_CORNERS[:, 2] > 0, (z2 + margin_m)[:, None], (z1 - margin_m)[:, None])
    world = np.einsum("pij,pkj->pki", pose.rotation, local) + pose.translation[:, None, :]
    return world.reshape(-1, 3)


def motion_margins(model: BodyModel, params: np.ndarray, previous: np.ndarray, *, base_m: float = 0.02,
                   gain: float = 1.0, max_m: float = 0.5) -> np.ndarray:
    """Per-part margins for :func:`pose_rois` from the predicted motion.

    Each part's margin is ``base_m + gain * motion``, where ``motion`` is the largest displacement of
    the part's box corners between ``previous`` (the pose the prediction starts from, e.g. the last
    fit) and ``params`` (the prediction), capped at ``max_m``; ``gain`` 1 covers a part that stops
    or doubles its speed, and (every corner at ``previous`` being within that distance of one at
    ``params``) the rectangle then also holds the one of ``previous``: no union of the two needed.
    Poses that are not finite give ``max_m`` everywhere.

    Parameters
    ----------
    model : BodyModel
    params, previous : ndarray, shape (n_params,)
    base_m, gain, max_m : float
        Metres, dimensionless, metres; finite, >= 0, ``base_m <= max_m``.

    Returns
    -------
    ndarray, shape (n_parts,)
        Metres.
    """
    for name, v in (("base_m", base_m), ("gain", gain), ("max_m", max_m)):
        if not (np.isfinite(v) and v >= 0):
            raise ValueError(f"{name}: expected a finite value >= 0, got {v!r}")
    if base_m > max_m:
        raise ValueError(f"base_m, max_m: expected base_m <= max_m, got {base_m!r}, {max_m!r}")
    poses = [np.asarray(p, dtype=float) for p in (params, previous)]
    for name, p in zip(("params", "previous"), poses):
        if p.shape != (model.n_params,):
            raise ValueError(f"{name}: expected shape ({model.n_params},), got {p.shape}")
    if not all(np.all(np.isfinite(p)) for p in poses):
        return np.full(model.n_parts, float(max_m))
    a, b = (part_box_corners(model, forward(model, p)).reshape(model.n_parts, 8, 3) for p in poses)
    motion = np.linalg.norm(a - b, axis=-1).max(axis=1)
    return np.minimum(base_m + gain * motion, max_m)


def pose_rois(model: BodyModel, params: np.ndarray, cameras: Sequence[Camera], *, margin_m=0.05,
              margin_px: int = 4) -> list[tuple[int, int, int, int] | None]:
    """Region of interest of every camera for the body at ``params`` (module docstring).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,) or (n_poses, n_params)
        The pose, e.g. the tracker's prediction for the frame; several poses: the rectangle around
        all of them (e.g. the last fitted pose and the prediction: the path between them).
    cameras : sequence of Camera
    margin_m : float or ndarray, shape (n_parts,)
        Every part's box grown by this much (metres): the prediction's expected error; one per part
        e.g. from :func:`motion_margins`.
    margin_px : int
        The rectangle grown by this much (pixels).

    Returns
    -------
    list, one per camera, of ``(x0, y0, x1, y1)`` (ints, half-open, inside the image) or None
    (segment the whole frame).  A body wholly outside a camera's image gives the smallest valid
    rectangle at the nearest image border (``segment_frame`` then finds nothing there).
    """
    margin = np.asarray(margin_m, dtype=float)
    if margin.shape not in ((), (model.n_parts,)) or not np.all(np.isfinite(margin) & (margin >= 0)):
        raise ValueError(f"margin_m: expected finite values >= 0, one or one per part ({model.n_parts}), "
                         f"got {margin_m!r}")
    if int(margin_px) != margin_px or margin_px < 0:
        raise ValueError(f"margin_px: expected an integer >= 0, got {margin_px!r}")
    params = np.asarray(params, dtype=float)
    if params.shape[-1:] != (model.n_params,) or params.ndim not in (1, 2) or not params.size:
        raise ValueError(f"params: expected shape ({model.n_params},) or (n_poses, {model.n_params}), "
                         f"got {params.shape}")
    cameras = list(cameras)
    if not np.all(np.isfinite(params)) or not cameras:
        return [None for _ in cameras]
    corners = np.concatenate([part_box_corners(model, forward(model, p), margin_m=margin)
                              for p in params.reshape(-1, model.n_params)])
    st = stack_cameras(cameras)
    depth = corners @ st.rotation[:, 2, :].T + st.translation[:, 2]  # (n_corners, n_cams)
    uv = project_many(cameras, np.broadcast_to(corners, (len(cameras),) + corners.shape))  # (n_cams, n, 2)
    size = np.array([[int(v) for v in cam.size] for cam in cameras])  # (n_cams, 2): w, h
    with np.errstate(invalid="ignore"):
        lo = np.floor(uv.min(axis=1)) - margin_px
        hi = np.ceil(uv.max(axis=1)) + margin_px + 1  # half-open
        ok = np.all(depth > _MIN_DEPTH_M, axis=0) & np.all(np.isfinite(uv), axis=(1, 2))
        x0y0 = np.clip(lo, 0, size - 1)
        x1y1 = np.clip(hi, x0y0 + 1, size)
    return [(int(a[0]), int(a[1]), int(b[0]), int(b[1])) if good else None
            for a, b, good in zip(x0y0, x1y1, ok)]
