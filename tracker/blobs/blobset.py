"""Blobs attached to a body model's parts (Caillette & Howard, BMVC'04 §4.1–4.3).

Each blob sits at a fixed point on a part's bone axis (part frame), one per equal slice of the
part's truncated cone: two on the long parts (torso, upper arms, forearms, thighs, shanks), one on
the others, none on the clavicles (hidden inside the torso).  Its prior shape is that slice as a
solid elliptic cylinder (variances ``a²/4, b²/4, L²/12`` in the part frame) and its prior volume the
slice's volume.  Face and hands have a skin-colour prior.

:class:`BlobSet` holds the learned state: the shape in the part frame, the colour Gaussian, and
whether each blob is active.  :meth:`BlobSet.regenerate` re-creates the blobs from a pose before
every expectation step (§4.3: their position from the kinematic model, their attributes from the
previous maximisation), :meth:`BlobSet.absorb` takes a maximisation's statistics, blending colour
with the prior by ``colour_prior_weight`` (strong on skin blobs) and de-activating a blob whose
filling falls below ``min_fill`` of its prior volume (occluded or off the hull; it still receives
voxels and comes back when its filling does).  :func:`learn_blobs` learns shape and colour from the
hull of the first frame at a known pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.blobs.em import BlobStats, expectation, maximisation
from tracker.body.kinematics import Pose, forward
from tracker.body.model import BodyModel

__all__ = ["BlobLayout", "BlobSet", "blob_layout", "learn_blobs", "SKIN_BGR", "SKIN_COV"]

#: Generic skin colour prior (BGR levels) and its covariance: skin tones of the synthetic studio
#: and of indoor webcam footage sit within ~2 sd of it.
SKIN_BGR = np.array([110.0, 140.0, 185.0])
SKIN_COV = np.diag([35.0, 35.0, 40.0]) ** 2

_TWO_BLOB_PARTS = ("torso", "upper_arm", "forearm", "thigh", "shank")
_SKIN_PARTS = ("head", "hand")


@dataclass(frozen=True, eq=False)
class BlobLayout:
    """Where the blobs sit on a model.

    names : tuple of str, length b; part : (b,) int part index; point : (b, 3) attachment point in
    the part frame, m; shape : (b, 3, 3) prior position covariance in the part frame, m²;
    volume : (b,) prior volume, m³; skin : (b,) bool, skin-colour prior.
    """

    names: tuple
    part: np.ndarray
    point: np.ndarray
    shape: np.ndarray
    volume: np.ndarray
    skin: np.ndarray

    @property
    def n_blobs(self) -> int:
        return len(self.names)


def blob_layout(model: BodyModel) -> BlobLayout:
    """The blobs of ``model`` (module docstring)."""
    names, part, point, shape, volume, skin = [], [], [], [], [], []
    for p, pname in enumerate(model.part_names):
        if "clavicle" in pname:
            continue
        a, b, k, z1, z2 = model.cones[p]
        n = 2 if any(t in pname for t in _TWO_BLOB_PARTS) else 1
        L = (z2 - z1) / n
        for i in range(n):
            zc = z1 + (i + 0.5) * L
            f = max(1.0 + k * zc, 0.05)
            names.append(pname if n == 1 else f"{pname}.{i}")
            part.append(p)
            point.append([0.0, 0.0, zc])
            shape.append(np.diag([(a * f) ** 2 / 4.0, (b * f) ** 2 / 4.0, L**2 / 12.0]))
            volume.append(np.pi * a * b * f * f * L)
            skin.append(any(t in pname for t in _SKIN_PARTS))
    return BlobLayout(tuple(names), np.array(part), np.array(point), np.array(shape), np.array(volume),
                      np.array(skin, bool))


@dataclass(eq=False)
class BlobSet:
    """The learned blobs of one subject (mutable tracking state).

    layout : BlobLayout; shape : (b, 3, 3) position covariance in the part frame, m²;
    colour, colour_cov : (b, 3), (b, 3, 3) colour Gaussian, BGR; point : (b, 3) attachment point in
    the part frame, m (the layout's); colour_prior, colour_prior_cov :
    what the colour is pulled back to (learned at initialisation, skin-blended on skin blobs);
    active : (b,) bool; fill : (b,) last filling (received volume / prior volume);
    mean, cov : (b, 3), (b, 3, 3) world position Gaussian of the last regeneration.
    """

    layout: BlobLayout
    shape: np.ndarray
    colour: np.ndarray
    colour_cov: np.ndarray
    colour_prior: np.ndarray
    colour_prior_cov: np.ndarray
    point: np.ndarray = field(default=None)
    active: np.ndarray = field(default=None)
    fill: np.ndarray = field(default=None)
    mean: np.ndarray = field(default=None)
    cov: np.ndarray = field(default=None)

    def __post_init__(self):
        b = self.layout.n_blobs
        if self.point is None:
            self.point = self.layout.point.copy()
        if self.active is None:
            self.active = np.ones(b, bool)
        if self.fill is None:
            self.fill = np.ones(b)

    def attachment(self, model: BodyModel, pose: Pose) -> np.ndarray:
        """World positions of the attachment points at ``pose``, (b, 3)."""
        return pose.to_world(self.layout.part, self.point)

    def regenerate(self, model: BodyModel, pose: Pose) -> None:
        """Place the blobs on the model at ``pose`` (means and position covariances, world)."""
        R = pose.rotation[self.layout.part]
        self.mean = self.attachment(model, pose)
        self.cov = R @ self.shape @ R.transpose(0, 2, 1)

    def absorb(self, stats: BlobStats, *, colour_prior_weight: np.ndarray, min_fill: float = 0.3,
               min_voxels: int = 3) -> None:
        """Take a maximisation's colour statistics and update filling and activity (module docstring)."""
        self.fill = stats.volume / self.layout.volume
        got = (stats.count >= min_voxels) & np.isfinite(stats.colour).all(1)
        beta = np.asarray(colour_prior_weight, float)[:, None]
        new = (1.0 - beta) * np.where(got[:, None], stats.colour, self.colour) + beta * self.colour_prior
        b2 = beta[..., None]
        new_cov = (1.0 - b2) * np.where(got[:, None, None], stats.colour_cov, self.colour_cov) + b2 * self.colour_prior_cov
        self.colour = np.where(self.active[:, None], new, self.colour)
        self.colour_cov = np.where(self.active[:, None, None], new_cov, self.colour_cov)
        self.active = self.fill >= min_fill


def learn_blobs(model: BodyModel, params: np.ndarray, centres: np.ndarray, sizes: np.ndarray,
                colours: np.ndarray, *, layout: BlobLayout | None = None, skin_weight: float = 0.3,
                shape_weight: float = 0.5, rounds: int = 2, offset_weight: float = 0.0,
                max_offset_m: float = 0.05) -> BlobSet:
    """Blobs learned from a coloured hull at a known pose.

    ``centres`` (n, 3), ``sizes`` (n,), ``colours`` (n, v, 3): the hull's voxels.  Voxels are first
    assigned by position alone (prior shapes, colour taken as the median over views), then
    ``rounds`` expectation–maximisation rounds with colour refine the colours; skin blobs' colour is
    blended with :data:`SKIN_BGR` by ``skin_weight``, and the learned shape (in the part frame) with
    the prior by ``shape_weight``.
    """
    layout = layout or blob_layout(model)
    b = layout.n_blobs
    pose = forward(model, params)
    grey = np.full((b, 3), 128.0)
    blobs = BlobSet(layout, layout.shape.copy(), grey, np.repeat((60.0**2 * np.eye(3))[None], b, 0),
                    grey.copy(), np.repeat((60.0**2 * np.eye(3))[None], b, 0))
    blobs.regenerate(model, pose)
    asg = expectation(centres, colours, blobs.mean, blobs.cov, blobs.colour, blobs.colour_cov, colour_weight=0.0)
    stats = maximisation(asg, centres, sizes, b)
    for r in range(rounds + 1):
        got = np.isfinite(stats.colour).all(1) & (stats.count >= 3)
        colour = np.where(got[:, None], stats.colour, 128.0)
        ccov = np.where(got[:, None, None], stats.colour_cov, 60.0**2 * np.eye(3))
        sk = layout.skin[:, None]
        colour = np.where(sk, (1 - skin_weight) * colour + skin_weight * SKIN_BGR, colour)
        ccov = np.where(sk[..., None], (1 - skin_weight) * ccov + skin_weight * SKIN_COV, ccov)
        blobs.colour, blobs.colour_cov = colour, ccov
        if r == rounds:
            break
        asg = expectation(centres, colours, blobs.mean, blobs.cov, blobs.colour, blobs.colour_cov)
        stats = maximisation(asg, centres, sizes, b)
    # learned shape in the part frame, blended with the prior
    R = pose.rotation[layout.part]
    got = np.isfinite(stats.cov).all((1, 2)) & (stats.count >= 10)
    learned = R.transpose(0, 2, 1) @ np.where(got[:, None, None], stats.cov, blobs.cov) @ R
    blobs.shape = shape_weight * layout.shape + (1 - shape_weight) * learned
    if offset_weight > 0:
        got_m = np.isfinite(stats.mean).all(1) & (stats.count >= 10)
        t = pose.translation[layout.part]
        local = np.einsum("bji,bj->bi", R, np.where(got_m[:, None], stats.mean, blobs.mean) - t)
        shift = offset_weight * (local - layout.point)
        norm = np.linalg.norm(shift, axis=1, keepdims=True)
        shift *= np.minimum(1.0, max_offset_m / np.maximum(norm, 1e-12))
        blobs.point = layout.point + shift
    blobs.colour_prior, blobs.colour_prior_cov = blobs.colour.copy(), blobs.colour_cov.copy()
    blobs.fill = stats.volume / layout.volume
    blobs.active = np.ones(b, bool)
    return blobs
