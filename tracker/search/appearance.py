"""Front/back evidence the silhouettes do not carry: the colours of each part's front and back, and the feet.

A body and its front/back mirror (``tracker.search.mirror.mirror_params``: turned 180°, left and
right exchanged) cast nearly the same silhouettes in a T-pose.  Two things tell them apart here:

* **Colour** (``surface_colours``): the images sampled at the projected model surface, per part
  and per half (``FRONT``: the part frame's +x side — the face, the chest, the front of a limb;
  ``BACK``), on points that face the camera, are not hidden by a nearer part and lie on the
  silhouette.  Under the mirror the same image colours land on the other part and the other half
  (``mirror_samples``), so a colour model learned once the pose is right
  (``AppearanceModel``) scores the true labelling better whenever the clothing or the head is not
  the same front and back or left and right.  Before anything is learned, ``head_cue`` compares
  the head's two halves with the subject's skin (the hands and forearms, else a generic skin
  colour): a face is skin, the back of a head is mostly hair (BMVC'04 colour blobs with a skin prior).
* **Feet** (``feet_forward``): the feet reach forward; on the floor ahead of a standing pose's hips
  (the way its pelvis faces) every silhouette holds a foot, behind them the heels end and some
  views see floor.

Colours are features ``(r, b, L)``: red and blue chromaticity with a darkness floor
(``B + G + R + 30`` in the denominator keeps dark colours stable) and the brightness on a 0–1 scale.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping, Sequence

import cv2
import numpy as np

from capture.camera import Camera
from tracker.body.kinematics import forward
from tracker.body.model import BodyModel

__all__ = ["FRONT", "BACK", "ColourSamples", "surface_colours", "view_colours", "mirror_samples", "AppearanceModel", "head_cue",
           "feet_forward", "colour_features", "SKIN_BGR"]

FRONT, BACK = 0, 1
#: A generic skin colour (BGR, 0–255) for the head cue when the hands and forearms show none.
SKIN_BGR = (120.0, 150.0, 200.0)
_DARK = 30.0


def colour_features(bgr: np.ndarray) -> np.ndarray:
    """BGR colours (..., 3) (0–255) -> features (..., 3): ``(R, B) / (B + G + R + 30)`` and
    ``(B + G + R) / 765``."""
    c = np.asarray(bgr, dtype=np.float32)
    s = c.sum(axis=-1, keepdims=True)
    return np.concatenate([c[..., 2:3] / (s + _DARK), c[..., 0:1] / (s + _DARK), s / 765.0], axis=-1)


@lru_cache(maxsize=8)
def _layout(model: BodyModel, n_theta: int, n_z: int):
    """Surface points (n_parts, m, 3) and outward normals (n_parts, m, 3) in the part frames, the
    half of each (n_parts, m) (FRONT/BACK) and the parts sampled (n_parts,) bool (not the feet:
    their frame's x is not the body's front)."""
    a, b, k, z1, z2 = (model.cones[:, i][:, None, None] for i in range(5))
    s = (np.arange(n_z) + 0.5) / n_z  # cross-sections inside the part, not on its end caps
    z = z1 + (z2 - z1) * s[None, :, None]
    theta = (np.arange(n_theta) + 0.5) * 2 * np.pi / n_theta
    r = 1.0 + k * z
    ct, st = np.cos(theta)[None, None, :], np.sin(theta)[None, None, :]
    pts = np.stack(np.broadcast_arrays(a * r * ct, b * r * st, z), axis=-1).reshape(model.n_parts, -1, 3)
    nrm = np.stack(np.broadcast_arrays(ct / a, st / b, np.zeros_like(z * ct)), axis=-1).reshape(model.n_parts, -1, 3)
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    side = np.where(pts[..., 0] >= 0.0, FRONT, BACK)
    used = np.array([not n.endswith("foot") for n in model.part_names])
    for arr in (pts, nrm, side, used):
        arr.setflags(write=False)
    return pts, nrm, side, used


@dataclass(frozen=True, eq=False)
class ColourSamples:
    """Per part and half: mean colour feature ``mean`` (n_parts, 2, 3) (``colour_features``; 0
    where unseen) and sample count ``count`` (n_parts, 2); ``bgr`` (n_parts, 2, 3) the mean BGR."""

    mean: np.ndarray
    count: np.ndarray
    bgr: np.ndarray


def _part_labels(uv: np.ndarray, depth: np.ndarray, camera: Camera, scale: float) -> np.ndarray:
    """Coarse label image (h', w') int16 (-1 = none) of the parts' projected convex hulls drawn far
    to near; ``uv`` (n_parts, m, 2) pixels and ``depth`` (n_parts, m) of their surface points."""
    w, h = max(1, int(round(camera.width * scale))), max(1, int(round(camera.height * scale)))
    img = np.full((h, w), -1, np.int16)
    fixed = (np.nan_to_num(np.clip(uv * scale, -1e5, 1e5)) * 16.0).astype(np.int32)  # 4 fractional bits
    front = depth > 0.05
    for p in np.argsort(-depth.mean(axis=1)):
        if np.count_nonzero(front[p]) >= 3:
            cv2.fillConvexPoly(img, cv2.convexHull(fixed[p][front[p]]), int(p), shift=4)
    return img


def surface_colours(model: BodyModel, params: np.ndarray, cameras: Sequence[Camera], images: Sequence[np.ndarray],
                    chamfer: Sequence | None = None, *, n_theta: int = 12, n_z: int = 3, min_facing: float = 0.4,
                    label_scale: float = 0.5) -> ColourSamples:
    """Image colours at the model surface of ``params`` (n_parts halves, see the module docstring).

    cameras : sequence of Camera; images : (h, w, 3) BGR uint8, one per camera; chamfer : the
    cameras' ``ChamferImages`` (samples off the observed silhouette are dropped) or None.
    A point counts in a camera when its normal is within acos(``min_facing``) of the direction to
    the camera, its pixel belongs to its own part in a coarse label image (``label_scale``) and it
    lies on the silhouette.  The cameras' samples pooled (``view_colours`` keeps them apart).
    """
    sums, bgr_sums, count = _view_sums(model, params, cameras, images, chamfer, n_theta, n_z, min_facing, label_scale)
    return _means(sums.sum(axis=0), bgr_sums.sum(axis=0), count.sum(axis=0))


def view_colours(model: BodyModel, params: np.ndarray, cameras: Sequence[Camera], images: Sequence[np.ndarray],
                 chamfer: Sequence | None = None, *, n_theta: int = 12, n_z: int = 3, min_facing: float = 0.4,
                 label_scale: float = 0.5, parts: Sequence[int] | None = None) -> ColourSamples:
    """``surface_colours`` per camera: a ColourSamples whose arrays have a leading camera axis
    (``mean`` (n_cameras, n_parts, 2, 3), ``count`` (n_cameras, n_parts, 2), ``bgr`` likewise).
    ``parts``: sample only these part indices (the others still hide them; None: all)."""
    return _means(*_view_sums(model, params, cameras, images, chamfer, n_theta, n_z, min_facing, label_scale, parts))


def _view_sums(model, params, cameras, images, chamfer, n_theta, n_z, min_facing, label_scale, parts=None):
    """Per camera: the feature and BGR sums (n_cameras, n_parts, 2, 3) and counts (n_cameras, n_parts, 2)."""
    local, normals, side, used = _layout(model, n_theta, n_z)
    if parts is not None:
        used = used & np.isin(np.arange(model.n_parts), np.asarray(parts, dtype=int))
    pose = forward(model, np.asarray(params, dtype=float))
    world = np.einsum("pij,pmj->pmi", pose.rotation, local) + pose.translation[:, None, :]
    nworld = np.einsum("pij,pmj->pmi", pose.rotation, normals)
    part = np.broadcast_to(np.arange(model.n_parts)[:, None], side.shape)
    n_views = len(cameras)
    sums = np.zeros((n_views, model.n_parts, 2, 3))
    bgr_sums = np.zeros((n_views, model.n_parts, 2, 3))
    count = np.zeros((n_views, model.n_parts, 2))
    for k, (cam, img) in enumerate(zip(cameras, images)):
        img = np.asarray(img)
        if img.ndim != 3 or img.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"images[{cam.name!r}]: expected ({cam.height}, {cam.width}, 3), got {img.shape}")
        uv, depth = cam.project(world), cam.depth(world)
        labels = _part_labels(uv, depth, cam, label_scale)
        to_cam = cam.center - world
        facing = np.einsum("pmi,pmi->pm", nworld, to_cam) / np.linalg.norm(to_cam, axis=-1)
        ok = (facing > min_facing) & (depth > 0.05) & used[:, None] & np.all(np.isfinite(uv), axis=-1)
        ui, vi = np.rint(uv[..., 0]), np.rint(uv[..., 1])
        ok &= (ui >= 0) & (ui < cam.width) & (vi >= 0) & (vi < cam.height)
        lu = np.clip((ui * label_scale).astype(int), 0, labels.shape[1] - 1)
        lv = np.clip((vi * label_scale).astype(int), 0, labels.shape[0] - 1)
        ok &= labels[lv, lu] == part
        if chamfer is not None and chamfer[k] is not None:
            sel = np.flatnonzero(ok.ravel())
            if sel.size:
                d = chamfer[k].sample(uv.reshape(-1, 2)[sel]).d_sil
                off = np.zeros(ok.size, bool)
                off[sel[d > 0.5]] = True
                ok &= ~off.reshape(ok.shape)
        if not ok.any():
            continue
        colours = img[vi[ok].astype(int), ui[ok].astype(int)].astype(float)
        bins = 2 * part[ok] + side[ok]
        feats = colour_features(colours)
        n_bins = 2 * model.n_parts
        for c in range(3):
            sums[k, ..., c] = np.bincount(bins, feats[:, c], minlength=n_bins).reshape(-1, 2)
            bgr_sums[k, ..., c] = np.bincount(bins, colours[:, c], minlength=n_bins).reshape(-1, 2)
        count[k] = np.bincount(bins, minlength=n_bins).reshape(-1, 2)
    return sums, bgr_sums, count


def _means(sums: np.ndarray, bgr_sums: np.ndarray, count: np.ndarray) -> ColourSamples:
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count[..., None] > 0, sums / np.maximum(count, 1.0)[..., None], 0.0)
        bgr = np.where(count[..., None] > 0, bgr_sums / np.maximum(count, 1.0)[..., None], 0.0)
    return ColourSamples(mean, count, bgr)


@lru_cache(maxsize=8)
def _part_mirror(model: BodyModel) -> np.ndarray:
    names = list(model.part_names)
    out = []
    for n in names:
        other = ("right_" + n[5:]) if n.startswith("left_") else ("left_" + n[6:]) if n.startswith("right_") else n
        out.append(names.index(other) if other in names else names.index(n))
    arr = np.array(out)
    arr.setflags(write=False)
    return arr


def mirror_samples(model: BodyModel, samples: ColourSamples) -> ColourSamples:
    """The samples as the mirrored hypothesis labels them: each part's halves given to the part
    of the other side (``left_*`` <-> ``right_*``), front and back exchanged."""
    idx = _part_mirror(model)
    return ColourSamples(samples.mean[idx][:, ::-1], samples.count[idx][:, ::-1], samples.bgr[idx][:, ::-1])


class AppearanceModel:
    """Per part and half, the mean colour feature of a subject seen in poses taken as right.

    Parameters
    ----------
    model : BodyModel
    sigma : (3,) feature scale of a mismatch (chromaticities, brightness: shading and light
        change the brightness far more than the chromaticity)
    memory : sample weight kept per half (older frames fade once it is reached)
    """

    def __init__(self, model: BodyModel, *, sigma=(0.035, 0.035, 0.12), memory: float = 400.0) -> None:
        self.model = model
        self.sigma = np.asarray(sigma, dtype=float)
        self.memory = float(memory)
        self.mean = np.zeros((model.n_parts, 2, 3))
        self.weight = np.zeros((model.n_parts, 2))

    @property
    def learned(self) -> bool:
        return bool(np.count_nonzero(self.weight >= 10.0) >= 4)

    def update(self, samples: ColourSamples) -> None:
        """Blend a frame's samples in (per half, weighted by their counts)."""
        n = samples.count
        w = np.minimum(self.weight, self.memory)
        total = w + n
        with np.errstate(invalid="ignore", divide="ignore"):
            self.mean = np.where(total[..., None] > 0, (w[..., None] * self.mean + n[..., None] * samples.mean)
                                 / np.maximum(total, 1e-9)[..., None], self.mean)
        self.weight = total

    def mirrored(self) -> "AppearanceModel":
        """The model of the mirrored labelling (``mirror_samples``)."""
        out = AppearanceModel(self.model, sigma=tuple(self.sigma), memory=self.memory)
        idx = _part_mirror(self.model)
        out.mean, out.weight = self.mean[idx][:, ::-1].copy(), self.weight[idx][:, ::-1].copy()
        return out

    def distances(self, samples: ColourSamples, *, min_count: float = 3.0, clip: float = 9.0) -> np.ndarray:
        """Squared normalised feature distance (n_parts, 2) of the samples' halves to the model's
        (clipped at ``clip``; NaN where either side has fewer than ``min_count`` samples /
        10 learned)."""
        d = (((samples.mean - self.mean) / self.sigma) ** 2).sum(axis=-1)
        d = np.minimum(d, clip)
        return np.where((samples.count >= min_count) & (self.weight >= 10.0), d, np.nan)

    def part_distances(self, samples: ColourSamples, parts: Sequence[int], *, others: Sequence[int] | None = None,
                       min_count: float = 3.0, clip: float = 9.0) -> tuple[np.ndarray, np.ndarray]:
        """Per part of ``parts``: the samples' distance to its own learned colour (or its other side's,
        ``left_*`` <-> ``right_*``: sleeves and hands are alike both sides) and to the nearest learned
        half of any other part (of ``others``, None: all), each the sample-weighted mean over the part's halves seen
        (``min_count`` samples, 10 learned) of squared normalised feature distances clipped at
        ``clip``.  ``samples`` may carry leading axes (``view_colours``: one per camera); returns
        ``(own, other)``, each (..., len(parts)), NaN where no half is seen."""
        parts = np.asarray(parts, dtype=int)
        m, c = samples.mean[..., parts, :, :], samples.count[..., parts, :]  # (..., k, 2, 3), (..., k, 2)
        d = np.minimum((((m[..., None, None, :] - self.mean) / self.sigma) ** 2).sum(axis=-1), clip)  # (..., k, 2, P, 2)
        k = np.arange(parts.size)
        twin = _part_mirror(self.model)[parts]
        learned = self.weight >= 10.0
        own = np.stack([np.minimum(d[..., k, h, parts, h], np.where(learned[twin, h], d[..., k, h, twin, h], np.inf))
                        for h in (FRONT, BACK)], axis=-1)  # (..., k, 2)
        idx = np.arange(self.model.n_parts)[None, :]
        candidates = np.ones(self.model.n_parts, bool) if others is None else np.isin(idx[0], np.asarray(others, int))
        other_ok = learned[None, :, :] & ((idx != parts[:, None]) & (idx != twin[:, None]) & candidates)[..., None]
        other = np.where(other_ok[:, None], d, np.inf).min(axis=(-2, -1))  # (..., k, 2)
        w = np.where((c >= min_count) & (self.weight[parts] >= 10.0) & np.isfinite(other), c, 0.0)
        total = w.sum(axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = lambda x: np.where(total > 0, (w * np.where(w > 0, x, 0.0)).sum(axis=-1) / total, np.nan)  # noqa: E731
            return mean(own), mean(other)

    def evidence(self, samples: ColourSamples, *, min_pairs: int = 4) -> float:
        """How much better the samples fit as labelled than mirrored (``mirror_samples``): mean
        over the halves seen both ways of (distance mirrored − distance as labelled); 0 when
        fewer than ``min_pairs`` halves are comparable.  Positive: the labelling is right."""
        d = self.distances(samples)
        dm = self.distances(mirror_samples(self.model, samples))
        both = np.isfinite(d) & np.isfinite(dm)
        if np.count_nonzero(both) < min_pairs:
            return 0.0
        return float(np.mean(dm[both] - d[both]))


def head_cue(model: BodyModel, samples: ColourSamples, *, min_count: float = 3.0,
             sigma=(0.035, 0.035, 0.12), clip: float = 9.0) -> float:
    """Face against back of the head: (distance of the head's back half to skin) − (distance of
    its front half to skin), squared normalised feature distances clipped at ``clip``; skin is the
    mean of the hands and forearms where seen, else ``SKIN_BGR``.  Positive: the face is where
    the labelling puts it; 0 when a half of the head is unseen.  Under the mirrored labelling the
    cue changes sign."""
    names = model.part_names
    if "head" not in names:
        return 0.0
    h = names.index("head")
    if samples.count[h, FRONT] < min_count or samples.count[h, BACK] < min_count:
        return 0.0
    skin_parts = [i for i, n in enumerate(names) if n.endswith(("hand", "forearm"))]
    n = samples.count[skin_parts].sum()
    if n >= 10:
        skin = (samples.mean[skin_parts] * samples.count[skin_parts][..., None]).sum(axis=(0, 1)) / n
    else:
        skin = colour_features(np.array(SKIN_BGR))
    s = np.asarray(sigma, dtype=float)
    dist = lambda f: float(min((((f - skin) / s) ** 2).sum(), clip))  # noqa: E731
    return dist(samples.mean[h, BACK]) - dist(samples.mean[h, FRONT])


def feet_forward(model: BodyModel, params: np.ndarray, cameras: Sequence[Camera], chamfer: Sequence, *,
                 reach_m=(0.08, 0.11, 0.14), height_m: float = 0.035, max_ankle_m: float = 0.15,
                 max_offset_m: float = 0.15, inside_px: float = 1.5, pose=None) -> tuple[float, float]:
    """Whether the feet reach forward the way the pelvis faces, for a standing pose.

    For each leg whose ankle is near the floor (``max_ankle_m``) and within ``max_offset_m`` of
    the vertical through its hip (its pivot, ``BodyModel.pivots``: the thigh's origin),
    points ``reach_m`` ahead of it along the pelvis heading and as far behind it, ``height_m``
    above the floor, are tested against the silhouettes (inside: silhouette distance at most ``inside_px`` in a camera).  Returns the mean
    fractions of cameras holding them ``(ahead, behind)`` (NaN, NaN when no leg stands or no camera
    sees the points).  ``pose``: ``forward(model, params)`` when the caller has it.  It does not
    follow the model's feet: a turned-round fit can slide and twist its legs until its feet lie in
    the silhouettes, not its hips.
    """
    from tracker.body.kinematics import joint_centre_array
    from tracker.search.mirror import pelvis_heading

    p = np.asarray(params, dtype=float)
    pose = forward(model, p) if pose is None else pose
    jc = joint_centre_array(model, pose)
    names = list(model.joint_names)
    refs = []
    for side in ("left", "right"):
        if f"{side}_ankle" not in names or f"{side}_hip" not in names:
            continue
        ankle = jc[names.index(f"{side}_ankle")]
        hip = pose.to_world(*model.pivots([f"{side}_hip"]))[0]  # the leg hangs from the thigh's origin
        if ankle[2] < max_ankle_m and np.hypot(*(ankle[:2] - hip[:2])) < max_offset_m:
            refs.append(hip[:2])
    h = pelvis_heading(model, p)
    if not refs or not np.any(h):
        return float("nan"), float("nan")
    reach = np.concatenate([np.asarray(reach_m, dtype=float), -np.asarray(reach_m, dtype=float)])  # ahead, behind
    refs = np.asarray(refs)
    pts = np.empty((len(refs), reach.size, 3))
    pts[..., :2] = refs[:, None, :] + reach[None, :, None] * h
    pts[..., 2] = height_m
    pts = pts.reshape(-1, 3)
    inside, seen = np.zeros(len(pts)), np.zeros(len(pts))
    for cam, ch in zip(cameras, chamfer):
        if ch is None:
            continue
        uv = cam.project(pts)
        ok = (cam.depth(pts) > 0.05) & np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) \
            & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        if ok.any():
            inside[ok] += ch.sample(uv[ok]).d_sil <= inside_px
            seen[ok] += 1
    ahead = (np.arange(len(pts)) % reach.size) < reach.size // 2
    out = []
    for sel in (ahead, ~ahead):
        v = seen[sel] > 0
        out.append(float(np.mean(inside[sel][v] / seen[sel][v])) if v.any() else float("nan"))
    return out[0], out[1]
