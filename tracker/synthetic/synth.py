"""Synthetic frames rendered from BVH motion, with ground truth: the rendering maths of a synthetic session.

Pipeline per frame: BVH -> ``tracker.synthetic.retarget`` (model parameters) -> ``tracker.imaging.render``
(part labels per camera) -> colour: the ray-cast room (``tracker.synthetic.scene``), the body's cast
shadow on the floor (every cone point pushed along the light direction to z = 0, the convex hull
per part, the floor darkened by ``shadow_strength`` in all channels alike, so the chroma is kept),
body parts in clothing/skin colours shaded by a Lambert term per part and a darkening towards each
part's outline, then Gaussian pixel noise (``add_noise``: independent per pixel, channel and frame).
The cameras are a ring fitted to the clip (``tracker.synthetic.scene.fit_ring_cameras``) so the
subject stays in every view (``synthetic_studio``).

Writing a session directory (videos, calibration, ground truth, session.toml) is
``service.synthetic_session.make_synthetic_session``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from capture.camera import Camera
from tracker.body.kinematics import Pose, forward, joint_centre_array
from tracker.body.model import BodyModel
from tracker.imaging.render import BACKGROUND, body_points, fill_convex_hulls, internal_edges, render_label_images
from tracker.synthetic.retarget import Retargeted
from tracker.synthetic.scene import fit_ring_cameras, make_room_texture, render_background

__all__ = ["bundled_motion", "render_frame", "Palette", "make_palette", "add_noise", "SyntheticStudio",
           "synthetic_studio", "ground_truth_record"]

DATA_DIR = Path(__file__).resolve().parent / "data"


def bundled_motion(name: str = "scaled_131_03") -> Path:
    """Path of a BVH shipped in ``tracker/synthetic/data`` (CMU subject 131; see CREDITS.md there).

    Parameters
    ----------
    name : str
        ``scaled_131_01`` or ``scaled_131_03`` (``.bvh`` optional).

    Returns
    -------
    Path

    Raises
    ------
    FileNotFoundError
        No such motion (the available ones listed).
    """
    path = DATA_DIR / (name if name.endswith(".bvh") else f"{name}.bvh")
    if not path.is_file():
        known = sorted(p.stem for p in DATA_DIR.glob("*.bvh"))
        raise FileNotFoundError(f"no bundled motion {name!r}; available: {known}")
    return path


@dataclass(frozen=True, eq=False)
class Palette:
    """Colours and light of a synthetic subject.

    Attributes
    ----------
    colours : ndarray, shape (n_parts, 3)
        BGR per part, float.
    light : ndarray, shape (3,)
        Unit direction of the light, pointing down.
    back : ndarray, shape (n_parts, 3), or None
        BGR of each part's back half (the part frame's -x side: hair on the head, the back of a
        shirt; ``tracker.synthetic.tpose.sided_palette``); None: as ``colours``.
    """

    colours: np.ndarray
    light: np.ndarray
    back: np.ndarray | None = None


def make_palette(model: BodyModel, rng: np.random.Generator) -> Palette:
    """Skin on head, hands and forearms; a shirt on the trunk and upper arms; trousers; shoes.

    Parameters
    ----------
    model : BodyModel
    rng : numpy.random.Generator
        Draws the clothing colours and the light's azimuth.

    Returns
    -------
    Palette
    """
    skin = np.array([120.0, 150.0, 200.0]) * rng.uniform(0.8, 1.1)
    shirt = rng.uniform(30, 220, 3)
    trousers = rng.uniform(20, 110, 3)
    shoes = np.array([35.0, 35.0, 40.0])
    colours = np.empty((model.n_parts, 3))
    for i, name in enumerate(model.part_names):
        if name == "head" or name.endswith("hand") or name.endswith("forearm"):
            colours[i] = skin
        elif name.endswith("foot"):
            colours[i] = shoes
        elif name == "pelvis" or "thigh" in name or "shank" in name:
            colours[i] = trousers
        else:
            colours[i] = shirt
    az = rng.uniform(0, 2 * np.pi)
    light = np.array([0.45 * np.cos(az), 0.45 * np.sin(az), -1.0])
    return Palette(colours, light / np.linalg.norm(light))


def _shadow_mask(model: BodyModel, pose: Pose, camera: Camera, light: np.ndarray) -> np.ndarray:
    """Where the body's shadow falls on the floor in this view, (h, w) uint8 0/255."""
    pts = body_points(model, pose, n_theta=16, n_z=3)
    on_floor = pts - (pts[..., 2:3] / light[2]) * light  # slide along the light ray to z = 0
    uv = camera.project(on_floor)
    valid = camera.depth(on_floor) > 0.05
    mask = np.zeros((camera.height, camera.width), np.uint8)
    return fill_convex_hulls(mask, uv, valid, range(model.n_parts), [255] * model.n_parts)


def render_frame(
    model: BodyModel,
    pose: Pose,
    cameras: Sequence[Camera],
    backgrounds: Sequence[np.ndarray],
    floor_masks: Sequence[np.ndarray],
    palette: Palette,
    *,
    shadow: bool = True,
    shadow_strength: float = 0.4,
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Noise-free colour images and part labels of one pose (the module docstring's pipeline).

    Parameters
    ----------
    model : BodyModel
    pose : Pose
    cameras : sequence of Camera
    backgrounds : sequence of ndarray, each shape (h, w, 3), uint8
        The empty room per camera.
    floor_masks : sequence of ndarray, each shape (h, w), float32
        1 where the floor is seen (where the shadow may fall).
    palette : Palette
    shadow : bool
        Cast the body's shadow on the floor.
    shadow_strength : float
        Darkening of the floor in the shadow's core (0: none, 1: black).

    Returns
    -------
    images : list of ndarray, each shape (h, w, 3), uint8
        BGR.
    labels : list of ndarray, each shape (h, w), int16
        Part index per pixel, ``BACKGROUND`` where no part is.
    """
    labels = render_label_images(model, pose, cameras)
    axis = pose.rotation[:, :, 2]  # part z axes in world, (n_parts, 3)
    # Lambert on a cylinder about each axis, averaged over the lit half: ∝ sin(angle(axis, light))
    lit = np.sqrt(np.clip(1.0 - (axis @ -palette.light) ** 2, 0.0, 1.0))
    part_rgb = palette.colours * (0.55 + 0.45 * lit)[:, None]
    back_rgb = None if palette.back is None else palette.back * (0.55 + 0.45 * lit)[:, None]
    images = []
    for cam, lab, bg, floor in zip(cameras, labels, backgrounds, floor_masks):
        img = bg.copy()
        if shadow:
            sm = _shadow_mask(model, pose, cam, palette.light)
            roi = _roi(sm > 0, pad=4)
            if roi is not None:
                sm_r = cv2.GaussianBlur(sm[roi], (5, 5), 1.0).astype(np.float32) / 255.0 * floor[roi]
                img[roi] = np.clip(img[roi] * (1.0 - shadow_strength * sm_r)[..., None], 0, 255).astype(np.uint8)
        roi = _roi(lab != BACKGROUND, pad=2)
        if roi is not None:
            # darken towards each part's outline: a cheap rounded look
            lab_r = lab[roi]
            body = lab_r != BACKGROUND
            d = cv2.distanceTransform(np.where(internal_edges(lab_r) > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 3)
            rim = 0.7 + 0.3 * np.sqrt(np.minimum(d, 6.0) / 6.0)
            patch = img[roi]
            rgb = part_rgb[lab_r[body]]
            if back_rgb is not None:
                back = _back_sides(model, pose, cam, palette)[roi][body]
                rgb[back] = back_rgb[lab_r[body][back]]
            patch[body] = np.clip(rgb * rim[body][:, None], 0, 255).astype(np.uint8)
        images.append(img)
    return images, labels


def _back_sides(model: BodyModel, pose: Pose, camera: Camera, palette: Palette) -> np.ndarray:
    """Pixels (h, w) bool where a part whose back colour differs from its front shows its back
    half (part frame x < 0): per part, the nearer half drawn over the farther."""
    from tracker.imaging.render import cone_points

    out = np.zeros((camera.height, camera.width), np.uint8)
    sided = np.flatnonzero(np.any(palette.back != palette.colours, axis=1))
    if sided.size == 0:
        return out.astype(bool)
    local = cone_points(model, n_theta=16, n_z=3)
    pts = np.einsum("pij,pmj->pmi", pose.rotation, local) + pose.translation[:, None, :]
    front = local[..., 0] >= 0.0
    mid = pts.mean(axis=1)
    depth = camera.depth(mid)
    uv = camera.project(pts.reshape(-1, 3)).reshape(pts.shape[0], -1, 2)
    ok = camera.depth(pts.reshape(-1, 3)).reshape(pts.shape[:2]) > 0.05
    for p in sided[np.argsort(-depth[sided])]:  # far parts first
        facing = float((camera.center - mid[p]) @ pose.rotation[p][:, 0]) > 0.0  # the front half is nearer
        halves = [(~front[p], 1), (front[p], 0)] if facing else [(front[p], 0), (~front[p], 1)]
        for sel, value in halves:
            fill_convex_hulls(out, uv[p][None], (ok[p] & sel)[None], [0], [value])
    return out.astype(bool)


def _roi(mask: np.ndarray, *, pad: int) -> tuple[slice, slice] | None:
    """Bounding box of a (h, w) bool mask grown by ``pad`` pixels, or None if empty."""
    x, y, w, h = cv2.boundingRect(mask.astype(np.uint8))
    if w == 0 or h == 0:
        return None
    H, W = mask.shape
    return slice(max(y - pad, 0), min(y + h + pad, H)), slice(max(x - pad, 0), min(x + w + pad, W))


def add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Gaussian pixel noise, independent per pixel and channel.

    Parameters
    ----------
    img : ndarray, shape (h, w, 3), uint8
    sigma : float
        Standard deviation, grey levels (0: ``img`` unchanged).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (h, w, 3), uint8
    """
    if sigma <= 0:
        return img
    noisy = img.astype(np.float32) + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class SyntheticStudio:
    """Everything a synthetic session's frames are rendered from (``synthetic_studio``).

    Attributes
    ----------
    motion : Retargeted
        The model and its parameters per frame.
    poses : list of Pose
        ``forward`` of every frame's parameters.
    cameras : list of Camera
    palette : Palette
    backgrounds : list of ndarray, each shape (h, w, 3), uint8
        The empty room per camera, noise-free.
    floors : list of ndarray, each shape (h, w), float32
        1 where a camera's pixel sees the floor (where a shadow may fall), else 0.
    """

    motion: Retargeted
    poses: list
    cameras: list
    palette: Palette
    backgrounds: list
    floors: list

    def render(self, frame: int, *, shadow: bool = True) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """``render_frame`` of one frame: noise-free images and part labels per camera.

        Parameters
        ----------
        frame : int
        shadow : bool

        Returns
        -------
        images, labels
            As ``render_frame``.
        """
        return render_frame(self.motion.model, self.poses[frame], self.cameras, self.backgrounds, self.floors,
                            self.palette, shadow=shadow)


def synthetic_studio(motion: Retargeted, *, cameras: int | Sequence[Camera] = 6, size: tuple[int, int] = (800, 600),
                     seed: int = 0, rng: np.random.Generator, palette: Palette | None = None) -> SyntheticStudio:
    """Cameras, room, palette and light for rendering ``motion``.

    Parameters
    ----------
    motion : Retargeted
    cameras : int or sequence of Camera
        Number of ring cameras fitted to the motion, or explicit cameras.
    size : (int, int)
        (width, height) of ring cameras, pixels.
    seed : int
        Seed of the room texture.
    rng : numpy.random.Generator
        Draws the palette and the light (the caller's noise continues the same stream).
    palette : Palette, optional
        The subject's colours instead of the drawn ones (drawn all the same: the same noise).

    Returns
    -------
    SyntheticStudio
    """
    mdl = motion.model
    poses = [forward(mdl, p) for p in motion.params]
    if isinstance(cameras, int):
        pts = np.concatenate([body_points(mdl, pose, n_theta=8, n_z=2).reshape(-1, 3) for pose in poses])
        cams = fit_ring_cameras(pts, cameras, size=tuple(size))
    else:
        cams = list(cameras)
    drawn = make_palette(mdl, rng)
    palette = drawn if palette is None else palette
    reach = max(np.linalg.norm(c.center[:2]) for c in cams)
    texture = make_room_texture(seed, wall_radius_m=max(7.0, reach + 2.0), extent_m=max(8.0, reach + 3.0))
    rendered = [render_background(c, texture, with_floor_mask=True) for c in cams]
    return SyntheticStudio(motion, poses, cams, palette, [b for b, _ in rendered],
                           [f.astype(np.float32) for _, f in rendered])


def ground_truth_record(motion: Retargeted, frame: int, pose: Pose) -> dict:
    """The DESIGN.md pose record of a frame's true pose (``ground_truth.jsonl``).

    Parameters
    ----------
    motion : Retargeted
    frame : int
    pose : Pose
        ``forward`` of ``motion.params[frame]``.

    Returns
    -------
    dict
        ``frame, timestamp_ns, ok, model, params, joints {name: [x, y, z] metres}, height_m``.
    """
    mdl = motion.model
    joints = joint_centre_array(mdl, pose)
    return {
        "frame": frame,
        "timestamp_ns": int(round(frame * 1e9 / motion.fps)),
        "ok": True,
        "model": mdl.name,
        "params": [float(v) for v in motion.params[frame]],
        "joints": {n: [float(v) for v in joints[i]] for i, n in enumerate(mdl.joint_names)},
        "height_m": float(motion.height_m),
    }
