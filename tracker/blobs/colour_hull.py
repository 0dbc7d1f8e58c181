"""Coloured hierarchical visual hull from sampled background statistics (Caillette & Howard, BMVC'04 §3.2–3.3).

Every frame, a box around the predicted pose (the *zone of interest*, :func:`zone_of_interest`) is
cut into a coarse grid of cubes anchored on a world lattice (the same cube is the same cube from
one frame to the next).  A cube is projected into each view and a fixed ``k × k`` pattern of pixels
is taken over its projected footprint (side ``f · size / depth``); each sample gets the
background model's squared Mahalanobis distance ``d`` (``segmentation.samples``) — no silhouette
and no full-image pass, so the cost follows the number of cubes, not the image size.

With ``low`` / ``high`` the certainty thresholds on ``d`` (the segmentation's hysteresis pair),
a sample is background (``d < low``), foreground (``d > high``) or undecided; a cube, in one view:

- every sample background: **background** — dropped at once, without looking at the other views;
- background and foreground samples together: **edge** (it straddles the silhouette's outline);
- every sample foreground: **foreground**;
- otherwise: **unknown** (the paper's vote: its statistics sit between the thresholds).

The paper thresholds the samples' mean and variance; counting samples on either side of the same
two thresholds says the same thing and is not dominated by one saturated sample.  After every
view: a cube background in any view is dropped; one that is an edge somewhere is split into 8 and
the children classified again; one that is foreground everywhere is kept whole; one that is
unknown somewhere (and nowhere background or edge) takes the majority class of its 26 neighbours
at the same level (background, edge or foreground; neighbours that were never tested do not vote;
without voters it counts as an edge).  Above the finest level a background majority only splits
the cube (weakly foreground limbs — clothing close to the background's colour — are thinner than a
coarse cube and are dropped by their background neighbours otherwise).  At the finest level an edge
cube is kept when, in every view, the mean of its samples' distances clipped at ``high`` reaches ``low`` (the paper's
mean test; the clipping keeps one saturated sample from deciding: about a quarter of the samples
certain, or most of them weakly foreground, as on clothing close to the background's colour).
Camouflage (``HullOptions.camouflage``): a cube whose samples all fall below ``low`` in a view but
whose mean distance does not is unknown there, not background, and an undecided finest cube then
needs only ``camouflage_keep`` as its clipped mean: the voxel analogue of the segmentation's
camouflage window (a cloth a little off the background's colour over the whole footprint).
Shadow-like samples can be settled by the multi-view floor test (``floor``,
``tracker.blobs.floor_samples``).

Each kept cube stores its mean colour per view: the mean of its samples above ``low`` (all of them
when none is), BGR levels.  There is no visibility test: the tracker uses the view whose colour
fits a blob best (``tracker.blobs.em``).  The result is a ``tracker.search.hull.VoxelHull`` with colours
(:class:`ColourHull`), so the hull's moments, components and point clouds apply.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from capture.camera import Camera
from segmentation.background import BackgroundModel
from segmentation.samples import background_samples
from tracker.blobs.kernels import neighbour_vote, pattern_pixels, sample_colours, view_classes
from tracker.search.hull import VoxelHull, project_with_depth
from tracker.body.kinematics import forward
from tracker.body.model import BodyModel
from tracker.imaging.render import body_points

__all__ = ["ColourHull", "HullOptions", "coloured_hull", "zone_of_interest"]

BACKGROUND, EDGE, FOREGROUND, UNKNOWN = 0, 1, 2, 3

# the 8 children's lower-corner offsets in units of the child size, (8, 3)
_CHILDREN = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], dtype=float)



@dataclass(frozen=True, eq=False)
class ColourHull(VoxelHull):
    """A visual hull whose voxels carry a mean colour per view.

    Attributes (besides ``tracker.search.hull.VoxelHull``'s)
    ----------
    colours : ndarray, shape (n, n_views, 3), float32
        Mean BGR colour of each voxel's foreground samples in each view, levels 0–255.
    camera_names : tuple of str, length n_views
    samples : int
        Pixel samples taken in all (a cost figure).
    """

    colours: np.ndarray = None
    camera_names: tuple = ()
    samples: int = 0

    def mean_colours(self) -> np.ndarray:
        """Mean over views of each voxel's colour, shape (n, 3), BGR (for display)."""
        return self.colours.mean(axis=1) if len(self.colours) else np.zeros((0, 3), np.float32)


@dataclass(frozen=True)
class HullOptions:
    """Options of :func:`coloured_hull`.

    min_voxel_m : finest cube edge, metres; levels : splits below the coarse grid (coarse cube edge
    ``min_voxel_m · 2**levels``); low, high : certainty thresholds on the squared background distance
    (``segmentation.pipeline.SegmentationParams`` uses the same pair for silhouettes); samples :
    samples per side of the pattern at each level from the coarsest (the last entry serves the finer
    levels): ``k`` gives ``k²`` samples per cube and view; camouflage : a cube whose samples are all
    below ``low`` in a view but whose mean distance reaches this is unknown there rather than background
    (clothing close to the background's colour differs a little over all its samples, noise does not;
    0: off); camouflage_keep : with ``camouflage``, the mean clipped distance that keeps an undecided
    finest cube (instead of ``low``; 0: ``low``).
    """

    min_voxel_m: float = 0.03
    levels: int = 2
    low: float = 16.0
    high: float = 64.0
    samples: tuple = (4, 3, 3)
    camouflage: float = 6.0
    camouflage_keep: float = 10.0

    def __post_init__(self):
        if not (np.isfinite(self.min_voxel_m) and self.min_voxel_m > 0):
            raise ValueError(f"min_voxel_m: expected > 0, got {self.min_voxel_m!r}")
        if not 0 <= int(self.levels) <= 8:
            raise ValueError(f"levels: expected 0..8, got {self.levels!r}")
        if not 0 <= self.low <= self.high:
            raise ValueError(f"low, high: expected 0 <= low <= high, got {self.low!r}, {self.high!r}")
        if not (0 <= self.camouflage <= self.low and 0 <= self.camouflage_keep <= self.high):
            raise ValueError(f"camouflage, camouflage_keep: expected 0..low and 0..high, got {self.camouflage!r}, "
                             f"{self.camouflage_keep!r}")
        if not self.samples or any(int(k) < 1 for k in self.samples):
            raise ValueError(f"samples: expected positive samples per side, got {self.samples!r}")


def zone_of_interest(model: BodyModel, params: np.ndarray, *, margin_m: float = 0.25,
                     floor_z: float = 0.0) -> np.ndarray:
    """Box ``(2, 3)`` ``[lower, upper]`` around the body surface at ``params`` grown by ``margin_m``,
    world metres; vertically it always spans ``floor_z`` to the subject's height above the body's
    lowest point (plus the margin), so a pose predicted too low or too high cannot cut the head or
    the feet off the hull that should correct it."""
    pts = body_points(model, forward(model, params), n_theta=8, n_z=2).reshape(-1, 3)
    lo, hi = pts.min(0) - margin_m, pts.max(0) + margin_m
    lo[2] = floor_z
    hi[2] = max(hi[2], max(pts[:, 2].min(), floor_z) + model.height_m + margin_m)
    return np.stack([lo, hi])


@lru_cache(maxsize=16)
def _pattern(k: int) -> np.ndarray:
    """A ``k × k`` grid of offsets in the unit square centred on 0, shape (k², 2) (cached: not to be written)."""
    g = (np.arange(k) + 0.5) / k - 0.5
    u, v = np.meshgrid(g, g)
    return np.column_stack([u.ravel(), v.ravel()])


def _classify_view(cam: Camera, image: np.ndarray, background: BackgroundModel, centres: np.ndarray,
                   size: float, k: int, options: HullOptions, floor=None):
    """Classes (m,) int8 of cubes ``centres`` (m, 3) of edge ``size`` in one view, with their samples'
    distances (m, k²) and colours (m, k², 3)."""
    m = len(centres)
    uv, z = project_with_depth(cam, centres)
    front = z > 0.05
    f = float(cam.matrix[0, 0])
    side = np.where(front, f * size / np.where(front, z, 1.0), 0.0)
    uv = np.nan_to_num(uv, nan=-1e6, posinf=-1e6, neginf=-1e6)
    inside = front & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
    cols, rows = pattern_pixels(uv, side, _pattern(k), cam.width, cam.height)
    if floor is None:
        d, bgr = background_samples(background, image, cols, rows)
    else:
        d, bgr, plain, ratio = background_samples(background, image, cols, rows, terms=True)
        d = floor(cam.name, cols, rows, d, plain, ratio, np.repeat(np.arange(m), k * k))
    n = k * k
    d = d.reshape(m, n)
    cls = view_classes(d, inside, float(options.low), float(options.high), float(options.camouflage),
                       BACKGROUND, EDGE, FOREGROUND, UNKNOWN)
    return cls, d, bgr.reshape(m, n, 3)


def _neighbour_vote(cells: np.ndarray, cls: np.ndarray, todo: np.ndarray) -> np.ndarray:
    """The majority class (BACKGROUND, EDGE or FOREGROUND; ties go to EDGE, then FOREGROUND) of the
    26 neighbours of each cell ``cells[todo]`` among ``cells`` (m, 3) int64 with classes ``cls`` (m,);
    absent and unknown cells do not vote, and a cell without voters stays UNKNOWN.  Shape (t,) int8."""
    if todo.size == 0:
        return np.zeros(0, np.int8)
    return neighbour_vote(np.ascontiguousarray(cells, dtype=np.int64), np.ascontiguousarray(cls, dtype=np.int8),
                          np.asarray(todo, dtype=np.intp), BACKGROUND, EDGE, FOREGROUND, UNKNOWN)


def coloured_hull(cameras: Sequence[Camera], images: Sequence[np.ndarray], backgrounds: Sequence[BackgroundModel],
                  zone, *, options: HullOptions = HullOptions(), floor=None) -> ColourHull:
    """The coloured hull of the zone ``zone`` (module docstring).

    Parameters
    ----------
    cameras : sequence of Camera, length n_views
    images : sequence of ndarray, each (h, w, 3) uint8 BGR of its camera
    backgrounds : sequence of BackgroundModel, one per camera (same size as its images)
    zone : array_like, shape (2, 3)
        ``[lower, upper]`` box to reconstruct, world metres; the grid is the world lattice of the
        coarse cube size that covers it.
    floor : callable, optional
        ``(camera name, cols, rows, distance, plain, ratio, cube of each sample) -> distance``: the samples' distances
        after a floor test of shadow-like samples (``tracker.blobs.floor_samples.SampleFloorTest.for_frame``).
    """
    if not (len(cameras) == len(images) == len(backgrounds)) or not cameras:
        raise ValueError(f"cameras, images, backgrounds: expected the same non-zero length, got "
                         f"{len(cameras)}, {len(images)}, {len(backgrounds)}")
    box = np.asarray(zone, dtype=float).reshape(2, 3)
    if not (np.all(np.isfinite(box)) and np.all(box[1] > box[0])):
        raise ValueError(f"zone: expected [lower, upper] with upper > lower, got {box.tolist()}")
    levels = int(options.levels)
    size = options.min_voxel_m * 2.0**levels
    i0 = np.floor(box[0] / size).astype(np.int64)
    i1 = np.ceil(box[1] / size).astype(np.int64)
    cells = np.stack(np.meshgrid(*(np.arange(a, b) for a, b in zip(i0, i1)), indexing="ij"), -1).reshape(-1, 3)
    n_views = len(cameras)
    kept_c, kept_s, kept_f, kept_col = [], [], [], []
    n_samples = 0
    for level in range(levels + 1):
        if len(cells) == 0:
            break
        finest = level == levels
        k = int(options.samples[min(level, len(options.samples) - 1)])
        centres = (cells + 0.5) * size
        m = len(cells)
        cls = np.full(m, FOREGROUND, np.int8)
        alive = np.arange(m)
        seen = []  # per view: (indices tested, sample distances, sample colours)
        for cam, img, bg in zip(cameras, images, backgrounds):
            if alive.size == 0:
                break
            c, d, bgr = _classify_view(cam, img, bg, centres[alive], size, k, options, floor)
            n_samples += d.size
            seen.append((alive, d, bgr))
            prev = cls[alive]
            # background wins, then edge, then unknown, then foreground
            new = np.where(c == BACKGROUND, BACKGROUND,
                           np.where((prev == EDGE) | (c == EDGE), EDGE,
                                    np.where((prev == UNKNOWN) | (c == UNKNOWN), UNKNOWN, FOREGROUND)))
            cls[alive] = new
            alive = alive[new != BACKGROUND]
        unknown = np.flatnonzero(cls == UNKNOWN)
        vote = _neighbour_vote(cells, cls, unknown)
        if not finest:  # above the finest level a vote may keep a cube whole, not drop it
            vote = np.where(vote == FOREGROUND, FOREGROUND, EDGE).astype(np.int8)
        cls[unknown] = vote
        if finest:  # edges (and unknowns without voters) by the majority of their samples in every view
            keep = cls == FOREGROUND
            undecided = np.flatnonzero((cls == EDGE) | (cls == UNKNOWN))
            if undecided.size and len(seen) == n_views:
                ok = np.ones(undecided.size, bool)
                for idx, d, _ in seen:
                    row = np.searchsorted(idx, undecided)
                    ok &= np.minimum(d[row], options.high).mean(1) >= (options.camouflage_keep or options.low)
                keep[undecided[ok]] = True
        else:
            keep = cls == FOREGROUND
        sel = np.flatnonzero(keep)
        if sel.size and len(seen) == n_views:
            col = np.empty((sel.size, n_views, 3), np.float32)
            for vi, (idx, d, bgr) in enumerate(seen):
                row = np.searchsorted(idx, sel)
                col[:, vi] = sample_colours(d, bgr, row, float(options.low))
            kept_c.append(centres[sel]), kept_s.append(np.full(sel.size, size))
            kept_f.append(np.ones(sel.size, bool) if not finest else cls[sel] == FOREGROUND)
            kept_col.append(col)
        if finest:
            break
        split = (cls == EDGE) | (cls == UNKNOWN)
        cells = (2 * cells[split][:, None, :] + _CHILDREN.astype(np.int64)[None]).reshape(-1, 3)
        size *= 0.5
    centres = np.concatenate(kept_c) if kept_c else np.zeros((0, 3))
    sizes = np.concatenate(kept_s) if kept_s else np.zeros(0)
    full = np.concatenate(kept_f) if kept_f else np.zeros(0, bool)
    colours = np.concatenate(kept_col) if kept_col else np.zeros((0, n_views, 3), np.float32)
    coarse = options.min_voxel_m * 2.0**levels
    bounds = np.stack([i0 * coarse, i1 * coarse]).astype(float)
    return ColourHull(centres, sizes, full, bounds, float(options.min_voxel_m), colours=colours,
                      camera_names=tuple(c.name for c in cameras), samples=int(n_samples))
