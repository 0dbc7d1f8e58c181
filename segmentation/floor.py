"""Multi-view floor test of shadow-like pixels: is the darkening on the floor?

The background test (``segmentation.background``) explains a pixel darker than the background
but of its chroma as a cast shadow.  On a dark floor that also explains dark trousers and shoes:
a pixel cannot tell a shadow from a dark object of the floor's colour.  The calibrated cameras
can: a shadow lies *on the floor* (z = 0 in the calibration's world frame), so the floor point
behind a shadow pixel is darkened alike in every camera that sees it, while the floor point
behind a leg is the unchanged floor in the cameras that see past the leg.

For every *candidate* of camera i (plain distance ``> low``, shadow-relaxed distance ``<= low``)
the ray is cut with the floor (``X``), ``X`` is projected into every other camera j, and j's pixel
there votes:

- **body** when it is the unchanged floor (plain distance ``<= low``) and closer to it than to the
  floor darkened by i's brightness ratio ``s_i``;
- **shadow** when it is the floor darkened by ``s_i`` (distance ``<= low``) and closer to that;
- nothing otherwise (j sees the body there, or something else).

A candidate is body when its body votes outnumber its shadow votes, or when no other camera sees
its floor point at all (a cast shadow lies near the body, on the floor all cameras watch).  Body
candidates that survive an opening (with the pixels already foreground: thin lines of
view-dependent change, e.g. a glossy floor's reflection hidden by the person, are dropped) lose
the shadow relaxation (their distance becomes the plain one); the rest keep it.  Pixels whose ray
does not reach the floor in front of the camera are left alone.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import cv2
import numpy as np

from capture.camera import Camera
from segmentation.background import BGR2YUV, BackgroundModel
from segmentation.checks import check_image_bgr
from segmentation.samples import floor_vote, model_terms

__all__ = ["FloorShadows", "floor_points", "floor_votes"]


def floor_points(camera: Camera) -> np.ndarray:
    """Where each pixel's ray meets the floor z = 0, world metres; NaN where it does not (ray level
    or upward).

    Parameters
    ----------
    camera : Camera

    Returns
    -------
    ndarray, shape (h, w, 2), float32
        The floor point's (x, y).
    """
    w, h = camera.size
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    d = camera.rays(np.stack([u.ravel(), v.ravel()], axis=-1))
    c = camera.center
    down = d[:, 2] < -1e-6
    t = np.where(down, -c[2] / np.where(down, d[:, 2], -1.0), np.nan)
    xy = c[:2] + t[:, None] * d[:, :2]
    return xy.reshape(h, w, 2).astype(np.float32)


class FloorShadows:
    """The floor test of one studio (see the module docstring).

    Parameters
    ----------
    cameras : sequence of Camera
        Calibrated, world frame Z up with the floor at z = 0; at least 2.
    models : mapping of str to BackgroundModel
        Background model per camera name (each of its camera's image size).
    low : float
        The foreground threshold on the squared distance (the segmentation's hysteresis ``low``).
    open_px : int
        Radius of the opening of (foreground or body candidates) that body candidates must survive,
        pixels (0: none).
    stride : int
        Candidates vote on every ``stride``-th row and column; each decides for its block.
    """

    def __init__(self, cameras: Sequence[Camera], models: Mapping[str, BackgroundModel], *, low: float = 16.0,
                 open_px: int = 2, stride: int = 1) -> None:
        self.cameras = {c.name: c for c in cameras}
        if len(self.cameras) < 2:
            raise ValueError(f"cameras: the floor test needs at least 2 cameras, got {len(self.cameras)}")
        missing = sorted(set(self.cameras) - set(models))
        if missing:
            raise ValueError(f"models: no background model for camera(s) {missing}")
        for name, cam in self.cameras.items():
            if tuple(models[name].size) != tuple(cam.size):
                raise ValueError(f"models[{name!r}]: size {models[name].size} differs from the camera's {cam.size}")
        if not (np.isfinite(low) and low > 0):
            raise ValueError(f"low: expected a finite number > 0, got {low!r}")
        self.models = {n: models[n] for n in self.cameras}
        if not (isinstance(open_px, (int, np.integer)) and open_px >= 0):
            raise ValueError(f"open_px: expected an integer >= 0, got {open_px!r}")
        if not (isinstance(stride, (int, np.integer)) and 1 <= stride <= 8):
            raise ValueError(f"stride: expected an integer in 1..8, got {stride!r}")
        self.low = float(low)
        self.open_px = int(open_px)
        self.stride = int(stride)
        self._disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.open_px + 1, 2 * self.open_px + 1))
        self._floor = {n: floor_points(c) for n, c in self.cameras.items()}

    def refine(self, name: str, images: Mapping[str, np.ndarray], box, distance: np.ndarray, plain: np.ndarray,
               ratio: np.ndarray) -> np.ndarray:
        """Camera ``name``'s distance in ``box`` with the shadow relaxation withdrawn where the floor
        test finds body.

        Parameters
        ----------
        name : str
        images : mapping of str to ndarray, each (h, w, 3) uint8
            This frame set's BGR images; cameras missing here do not vote.
        box : (int, int, int, int)
            ``(x0, y0, x1, y1)`` of the three arrays below in camera ``name``'s image.
        distance, plain, ratio : ndarray, each shape (y1 - y0, x1 - x0), float32
            ``BackgroundModel.distance_terms`` of that box.

        Returns
        -------
        ndarray, shape (y1 - y0, x1 - x0), float32
            ``distance``, with ``plain`` at the candidates found to be body.
        """
        x0, y0, x1, y1 = box
        cand = (plain > self.low) & (distance <= self.low)
        if not cand.any():
            return distance
        step = self.stride  # vote on a grid; each grid pixel decides for its stride x stride block
        grid = cand[::step, ::step]
        rows, cols = np.nonzero(grid)
        rows, cols = rows * step, cols * step
        xy = self._floor[name][rows + y0, cols + x0]
        on_floor = np.isfinite(xy[:, 0])
        rows, cols, xy = rows[on_floor], cols[on_floor], xy[on_floor].astype(np.float64)
        X = np.concatenate([xy, np.zeros((xy.shape[0], 1))], axis=1)
        body = floor_votes(self.cameras, self.models, name, images, X, ratio[rows, cols], self.low)
        votes = np.zeros(grid.shape, np.uint8)
        votes[rows[body] // step, cols[body] // step] = 255
        h, w = distance.shape
        promoted = np.repeat(np.repeat(votes, step, axis=0), step, axis=1)[:h, :w]
        promoted[~cand] = 0
        if self.open_px > 0:  # thin promoted lines (a view-dependent change along a wall's base) go
            union = np.where(distance > self.low, np.uint8(255), promoted)
            promoted &= cv2.morphologyEx(union, cv2.MORPH_OPEN, self._disk)
        out = distance.copy()
        np.copyto(out, plain, where=promoted > 0)
        return out

    def for_camera(self, name: str, images: Mapping[str, np.ndarray]):
        """``refine`` bound to camera ``name`` and one frame set: the ``floor`` argument of
        ``segmentation.pipeline.segment_frame``, a callable ``(box, distance, plain, ratio) -> distance``."""
        if name not in self.cameras:
            raise ValueError(f"no camera {name!r} in the floor test (have {sorted(self.cameras)})")
        return lambda box, distance, plain, ratio: self.refine(name, images, box, distance, plain, ratio)


def floor_votes(cameras: Mapping[str, Camera], models: Mapping[str, BackgroundModel], name: str,
                images: Mapping[str, np.ndarray], points: np.ndarray, ratio: np.ndarray, low: float) -> np.ndarray:
    """The other cameras' vote on floor points seen darkened by camera ``name``: body or shadow.

    Parameters
    ----------
    cameras, models : mapping of str to Camera / BackgroundModel
        The studio, by camera name.
    name : str
        The camera whose shadow-like pixels are tested (it does not vote).
    images : mapping of str to ndarray, each (h, w, 3) uint8
        The frame set's BGR images; cameras missing here do not vote.
    points : ndarray, shape (m, 3)
        The floor points (z = 0) behind the candidates, world frame, metres.
    ratio : ndarray, shape (m,)
        Each candidate's brightness ratio to its background (the darkening a shadow would cast).
    low : float
        The foreground threshold on the squared distance.

    Returns
    -------
    ndarray of bool, shape (m,)
        Body: more cameras see the floor point unchanged than darkened alike, or none sees it.

    Notes
    -----
    A camera votes on a point in front of it whose undistorted projection lies within its image
    grown by a quarter on every side (far outside it the distortion polynomial can fold points back
    in) and whose distorted projection, rounded, is a pixel of the image; the two distances are
    ``BackgroundModel.distance_at``'s.  One compiled loop per voting camera
    (``segmentation.samples.floor_vote``).
    """
    m = len(points)
    body, shadow, seen = np.zeros(m, np.int32), np.zeros(m, np.int32), np.zeros(m, bool)
    points = np.ascontiguousarray(points, dtype=np.float64)
    ratio = np.ascontiguousarray(ratio, dtype=np.float32)
    for other, cam in cameras.items():  # a loop over cameras, not pixels
        if other == name or other not in images:
            continue
        image = images[other]
        check_image_bgr(image, f"images[{other!r}]", size=cam.size)
        pdiag, pcross, a, big_a, _ = model_terms(models[other])
        floor_vote(points, ratio, cam.rotation, cam.translation, cam.matrix, np.asarray(cam.distortion, float),
                   cam.size[0], cam.size[1], np.ascontiguousarray(image).reshape(-1, 3), pdiag, pcross, a, big_a,
                   BGR2YUV, float(low), body, shadow, seen)
    return (body > shadow) | ~seen
