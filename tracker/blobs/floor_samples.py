"""The multi-view floor test of shadow-like pixels, on the coloured hull's scattered samples.

The background test explains a pixel darker than the background but of its chroma as a cast
shadow; on a dark floor that also explains dark trousers and shoes, and a hull built on that test
loses the legs.  ``segmentation.floor`` settles it per image: a shadow lies on the floor, so the
floor point behind a shadow pixel is darkened alike in the other cameras, while the floor point
behind a leg is the unchanged floor where the other cameras see past the leg.  This module asks
the same question of the samples the hull takes (a few per voxel projection), so its cost follows
the number of candidate samples, not the image size.

For every *candidate* sample of camera i (plain distance ``> low``, shadow-relaxed distance
``<= low``; one per cube when the hull groups them) the floor point behind it is projected into
every other camera j, whose pixel there votes **body** (the unchanged floor: plain distance
``<= low`` and nearer than to the floor darkened by i's brightness ratio) or **shadow** (the
darkened floor, nearer to it).  A candidate with more body than shadow votes, or whose floor point
no other camera sees, takes its plain distance (with its cube's other candidates).
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np

from capture.camera import Camera
from segmentation.background import BackgroundModel
from segmentation.floor import floor_points, floor_votes

__all__ = ["SampleFloorTest"]


class SampleFloorTest:
    """The floor test of one studio for hull samples (module docstring).

    Parameters
    ----------
    cameras : sequence of Camera
        Calibrated, world frame Z up with the floor at z = 0; at least 2.
    backgrounds : mapping of str to BackgroundModel
        Per camera name, of its camera's image size.
    low : float
        The foreground threshold on the squared distance (the hull's ``HullOptions.low``).
    """

    def __init__(self, cameras: Sequence[Camera], backgrounds: Mapping[str, BackgroundModel], *,
                 low: float = 16.0) -> None:
        self.cameras = {c.name: c for c in cameras}
        if len(self.cameras) < 2:
            raise ValueError(f"cameras: the floor test needs at least 2 cameras, got {len(self.cameras)}")
        missing = sorted(set(self.cameras) - set(backgrounds))
        if missing:
            raise ValueError(f"backgrounds: no model for camera(s) {missing}")
        if not (np.isfinite(low) and low > 0):
            raise ValueError(f"low: expected a finite number > 0, got {low!r}")
        self.backgrounds = {n: backgrounds[n] for n in self.cameras}
        self.low = float(low)
        self._floor = {n: floor_points(c) for n, c in self.cameras.items()}

    def resolve(self, name: str, images: Mapping[str, np.ndarray], cols: np.ndarray, rows: np.ndarray,
                distance: np.ndarray, plain: np.ndarray, ratio: np.ndarray, group: np.ndarray | None = None
                ) -> np.ndarray:
        """Camera ``name``'s sample distances with the shadow relaxation withdrawn where the floor
        test finds body.

        Parameters
        ----------
        name : str
        images : mapping of str to ndarray, each (h, w, 3) uint8
            The frame set's BGR images; cameras missing here do not vote.
        cols, rows : ndarray of int, shape (m,)
            The samples' pixels in camera ``name``'s image (inside it).
        distance, plain, ratio : ndarray, shape (m,)
            ``segmentation.samples.background_samples(..., terms=True)`` of those pixels.
        group : ndarray of int, shape (m,), optional
            A group per sample (the hull's cube): one candidate per group is tested (the first) and
            its verdict applies to the group's candidates (the cost follows cubes, not samples).

        Returns
        -------
        ndarray, shape (m,), float32
        """
        distance = np.asarray(distance, np.float32)
        cand = np.flatnonzero((plain > self.low) & (distance <= self.low))
        if cand.size == 0:
            return distance
        owner = None
        if group is not None:
            g = np.asarray(group)[cand]
            _, first, owner = np.unique(g, return_index=True, return_inverse=True)
            full, cand = cand, cand[first]
        xy = self._floor[name][np.asarray(rows)[cand], np.asarray(cols)[cand]]
        on_floor = np.isfinite(xy[:, 0])
        kept = np.flatnonzero(on_floor)
        cand, xy = cand[on_floor], xy[on_floor].astype(np.float64)
        if cand.size == 0:
            return distance
        X = np.column_stack([xy, np.zeros(len(xy))])
        verdict = self.votes(name, images, X, np.asarray(ratio, np.float32)[cand])
        if owner is None:
            promote = cand[verdict]
        else:  # every candidate of a group whose tested candidate is body
            group_body = np.zeros(len(first), bool)
            group_body[kept[verdict]] = True
            promote = full[group_body[owner]]
        out = distance.copy()
        out[promote] = np.asarray(plain, np.float32)[promote]
        return out

    def votes(self, name: str, images: Mapping[str, np.ndarray], points: np.ndarray, ratio: np.ndarray) -> np.ndarray:
        """The other cameras' verdict on floor points (m, 3) seen darkened by ``ratio`` (m,) in camera
        ``name``: ``segmentation.floor.floor_votes``; (m,) bool."""
        return floor_votes(self.cameras, self.backgrounds, name, images, points, ratio, self.low)

    def for_frame(self, images: Mapping[str, np.ndarray]) -> Callable:
        """``resolve`` bound to one frame set: ``(name, cols, rows, distance, plain, ratio) -> distance``
        (the ``floor`` argument of ``tracker.blobs.colour_hull.coloured_hull``)."""
        return lambda name, cols, rows, distance, plain, ratio, group=None: self.resolve(
            name, images, cols, rows, distance, plain, ratio, group)
