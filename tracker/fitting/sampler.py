"""What the tracker reads from one camera's segmentation: the chamfer sampler protocol.

Every function of the tracker that takes chamfer images takes them as a **mapping camera name ->
sampler** (``Tracker.step``, ``fit_frame``, the searches of ``tracker.search``); the cameras it works
on are given separately and pick their samplers by name (``in_camera_order``).  Only the cost object
(``tracker.fitting.cost.ChamferCost``) holds them as a list aligned with its cameras.

A sampler is anything with ``sample(uv)``: the quantised distance images of
``segmentation.distance.ChamferImages`` (what the segmentation workers send), or a test's analytic
field.  The reverse (silhouette -> model) term of the cost and the tracker's empty-view check also
read ``silhouette_q`` and ``offset_xy`` where a sampler has them (``SilhouetteChamfer``).
"""

from __future__ import annotations

from typing import Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from capture.camera import Camera

__all__ = ["ChamferSampler", "SilhouetteChamfer", "ChamferViews", "in_camera_order"]


@runtime_checkable
class ChamferSampler(Protocol):
    """Distances to one camera's silhouette and edges, sampled at image points."""

    def sample(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Distances and their image gradients at full-image points.

        Parameters
        ----------
        uv : ndarray, shape (n, 2)
            Pixel coordinates (u, v); pixel (row i, col j) is centred at (j, i).

        Returns
        -------
        d_sil : ndarray, shape (n,)
            Distance to the silhouette in pixels (0 inside it).
        grad_sil : ndarray, shape (n, 2)
            Its gradient d/d(u, v), pixels per pixel.
        d_edge : ndarray, shape (n,)
            Distance to the nearest edge pixel inside the silhouette, pixels.
        grad_edge : ndarray, shape (n, 2)
            Its gradient d/d(u, v).
        """
        ...


@runtime_checkable
class SilhouetteChamfer(ChamferSampler, Protocol):
    """A sampler that also holds its silhouette distance image (what the reverse term samples).

    Attributes
    ----------
    silhouette_q : ndarray, shape (h, w), uint8 or uint16
        Quantised distance to the silhouette; 0 on the silhouette.
    offset_xy : tuple of int
        (x, y) of the array's top-left pixel in the full image.
    """

    silhouette_q: np.ndarray
    offset_xy: tuple[int, int]


#: The one convention for a frame set's chamfer inputs: camera name -> sampler.
ChamferViews = Mapping[str, ChamferSampler]


def in_camera_order(chamfer: ChamferViews, cameras: Sequence[Camera]) -> list[ChamferSampler]:
    """The samplers of ``cameras``, in their order (what ``ChamferCost`` takes).

    Parameters
    ----------
    chamfer : mapping str -> ChamferSampler
        Camera name -> sampler; may hold more cameras than ``cameras``.
    cameras : sequence of Camera, length n_cams

    Returns
    -------
    list of ChamferSampler, length n_cams

    Raises
    ------
    TypeError
        ``chamfer`` is not a mapping.
    ValueError
        A camera has no sampler (the message names it).
    """
    if not isinstance(chamfer, Mapping):
        raise TypeError(f"chamfer: expected a mapping camera name -> chamfer images, got {type(chamfer).__name__}")
    missing = [c.name for c in cameras if c.name not in chamfer]
    if missing:
        raise ValueError(f"chamfer: no chamfer images for camera(s) {missing}")
    return [chamfer[c.name] for c in cameras]
