"""Synthetic multi-camera sessions rendered from BVH motion, with ground truth.

``make_synthetic_session(bvh_path, out_dir, ...)`` writes a DESIGN.md
session directory::

    OUT/
      session.toml          [session] name, fps; [subject] height_m (+ segment_lengths
                            with fit_segments); [[camera]] name, video|images, background
      calibration.toml      capture.calibration.save_calibration (anipose layout)
      cam0.avi …            frame k = trigger pulse k (FFV1 by default: lossless)
      background/cam0.avi … the empty room, ``n_background`` frames, same noise
      ground_truth.jsonl    one DESIGN.md pose record per frame (frame, timestamp_ns, ok,
                            model, params, joints {name: [x, y, z]}, height_m)
      masks/cam0/000000.png true silhouettes (255 = body), with ``masks=True``

Pipeline per frame: BVH -> ``tracker.synthetic.retarget`` (model parameters) ->
``tracker.imaging.render`` (part labels per camera) -> colour: the ray-cast room
(``tracker.synthetic.scene``), the body's cast shadow on the floor (every cone
point pushed along the light direction to z = 0, the convex hull per
part, the floor darkened by ``shadow_strength`` in all channels alike, so
the chroma is kept), body parts in clothing/skin colours shaded by a
Lambert term per part and a darkening towards each part's outline, then
Gaussian pixel noise (``noise`` grey levels, independent per pixel,
channel and frame).  The cameras are a ring fitted to the clip
(``tracker.synthetic.scene.fit_ring_cameras``) so the subject stays in every view.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from capture.calibration import save_calibration
from capture.camera import Camera
from capture.session import write_session_toml
from tracker.synthetic.bvh import load_bvh
from tracker.body.kinematics import Pose, forward, joint_centre_array
from tracker.body.model import BodyModel
from tracker.imaging.render import BACKGROUND, body_points, fill_convex_hulls, internal_edges, render_label_images
from tracker.synthetic.retarget import Retargeted, retarget_bvh
from tracker.synthetic.scene import fit_ring_cameras, make_room_texture, render_background, ring_cameras

__all__ = ["make_synthetic_session", "bundled_motion", "render_frame", "Palette", "make_palette", "CODECS", "ring_cameras"]

DATA_DIR = Path(__file__).resolve().parent / "data"
CODECS = ("ffv1", "png", "mjpg")
_FOURCC = {"ffv1": "FFV1", "mjpg": "MJPG"}


def bundled_motion(name: str = "scaled_131_03") -> Path:
    """Path of a BVH shipped in ``tracker/data`` (CMU subject 131; see CREDITS.md there)."""
    path = DATA_DIR / (name if name.endswith(".bvh") else f"{name}.bvh")
    if not path.is_file():
        known = sorted(p.stem for p in DATA_DIR.glob("*.bvh"))
        raise FileNotFoundError(f"no bundled motion {name!r}; available: {known}")
    return path


@dataclass(frozen=True, eq=False)
class Palette:
    """Per-part BGR colours (n_parts, 3) float and the light direction (3,) (unit, pointing down);
    ``back`` (n_parts, 3) or None: the colours of the parts' back halves (the side of each part
    frame's -x: hair on the head, the back of a shirt; ``tracker.synthetic.tpose.sided_palette``)."""

    colours: np.ndarray
    light: np.ndarray
    back: np.ndarray | None = None


def make_palette(model: BodyModel, rng: np.random.Generator) -> Palette:
    """Skin on head, hands and forearms; a shirt on the trunk and upper arms; trousers; shoes."""
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
    """Noise-free colour images (BGR uint8 (h, w, 3)) and part labels ((h, w) int16) of one pose."""
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
    """(h, w) bool: pixels where a part whose back colour differs from its front shows its back
    half (part frame x < 0), the nearer half of the part drawn over the farther."""
    from tracker.imaging.render import cone_points

    out = np.zeros((camera.height, camera.width), np.uint8)
    sided = np.flatnonzero(np.any(palette.back != palette.colours, axis=1))
    if sided.size == 0:
        return out.astype(bool)
    local = cone_points(model, n_theta=16, n_z=3)
    pts = np.einsum("pij,pmj->pmi", pose.rotation, local) + pose.translation[:, None, :]
    front = local[..., 0] >= 0.0  # (n_parts, m)
    mid = pts.mean(axis=1)
    depth = camera.depth(mid)
    uv = camera.project(pts.reshape(-1, 3)).reshape(pts.shape[0], -1, 2)
    ok = camera.depth(pts.reshape(-1, 3)).reshape(pts.shape[:2]) > 0.05
    for p in sided[np.argsort(-depth[sided])]:  # far parts first
        facing = float((camera.center - mid[p]) @ pose.rotation[p][:, 0]) > 0.0  # the front half is nearer
        halves = [(front[p], 0), (~front[p], 1)] if not facing else [(~front[p], 1), (front[p], 0)]
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


def _add_noise(img: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    if sigma <= 0:
        return img
    noisy = img.astype(np.float32) + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


class _Sink:
    """One camera's output: a video file or a PNG sequence."""

    def __init__(self, root: Path, rel: str, codec: str, fps: float, size: tuple[int, int]):
        self.codec = codec
        self.frame = 0
        if codec == "png1":  # a single image
            self.rel = f"{rel}.png"
            (root / self.rel).parent.mkdir(parents=True, exist_ok=True)
            self.pattern = str(root / self.rel)
            self.writer = None
        elif codec == "png":
            self.rel = f"{rel}/%06d.png"
            (root / rel).mkdir(parents=True, exist_ok=True)
            self.pattern = str(root / self.rel)
            self.writer = None
        else:
            self.rel = f"{rel}.avi"
            (root / self.rel).parent.mkdir(parents=True, exist_ok=True)
            self.path = root / self.rel
            self.writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*_FOURCC[codec]), fps, size)
            if not self.writer.isOpened():
                raise RuntimeError(f"{root / self.rel}: OpenCV cannot write {codec} video here")

    def write(self, img: np.ndarray) -> None:
        if self.writer is None:
            path = self.pattern % self.frame if self.codec == "png" else self.pattern
            if not cv2.imwrite(path, img):
                raise OSError(f"cannot write {path}")
        else:
            self.writer.write(img)
        self.frame += 1

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()

    def check(self) -> None:
        """After ``close``: a video must hold every frame written (``cv2.VideoWriter`` reports no errors)."""
        if self.writer is None:
            return
        cap = cv2.VideoCapture(str(self.path))
        stored = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
        cap.release()
        if stored != self.frame:
            raise OSError(f"{self.path}: holds {stored} of the {self.frame} frames written (disk full?)")


def _video_codec_available(codec: str, tmp: Path) -> bool:
    probe = tmp / f".probe_{codec}.avi"
    w = cv2.VideoWriter(str(probe), cv2.VideoWriter_fourcc(*_FOURCC[codec]), 30.0, (16, 16))
    ok = w.isOpened()
    w.release()
    probe.unlink(missing_ok=True)
    return ok


def make_synthetic_session(
    bvh_path,
    out_dir,
    *,
    cameras: int | Sequence[Camera] = 6,
    size: tuple[int, int] = (800, 600),
    frames: int | None = None,
    fps: float = 30.0,
    start_s: float = 0.0,
    noise: float = 2.0,
    shadow: bool = True,
    model: str = "knossow40",
    seed: int = 0,
    codec: str = "ffv1",
    masks: bool = False,
    n_background: int = 50,
    fit_segments: bool = False,
    name: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    retargeted: Retargeted | None = None,
    palette: Palette | None = None,
) -> Path:
    """Render a synthetic session from BVH motion; returns ``out_dir``.

    Parameters
    ----------
    cameras : int or sequence of Camera
        Number of ring cameras (fitted to the motion), or explicit cameras.
    size : (width, height)
        Image size of ring cameras.
    frames : int, optional
        Number of frames at ``fps`` from ``start_s`` (default: the whole clip).
    noise : float
        Standard deviation of the Gaussian pixel noise, grey levels.
    codec : "ffv1" | "png" | "mjpg"
        Lossless FFV1 AVI (default; falls back to PNG sequences where this
        OpenCV cannot write FFV1), PNG sequences, or lossy MJPG.  Background
        media are always one file (what replay reads): a video in the chosen
        codec, FFV1 for "png", or a single PNG where no video codec works.
    masks : bool
        Also write true silhouettes ``masks/camN/%06d.png``.
    progress : callable, optional
        Called as ``progress(done, total)`` after each frame.
    retargeted : Retargeted, optional
        Reuse motion already retargeted (``bvh_path`` then only names the session).
    palette : Palette, optional
        The subject's colours (default ``make_palette`` drawn from ``seed``).
    """
    if codec not in CODECS:
        raise ValueError(f"codec must be one of {CODECS}, got {codec!r}")
    if noise < 0 or not np.isfinite(noise):
        raise ValueError(f"noise must be >= 0, got {noise}")
    if n_background < 1:
        raise ValueError(f"n_background must be >= 1, got {n_background}")
    if isinstance(cameras, int) and cameras < 1:
        raise ValueError(f"cameras must be >= 1, got {cameras}")
    # the motion first: a bad BVH or option leaves no empty output folder behind
    motion = retargeted or retarget_bvh(
        load_bvh(bvh_path), model=model, fps=fps, frames=frames, start_s=start_s, fit_segments=fit_segments
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ffv1_ok = _video_codec_available("ffv1", out)
    if codec != "png" and not _video_codec_available(codec, out):
        codec = "png"
    # replay reads a background as one video or one image (not a sequence)
    bg_codec = codec if codec != "png" else ("ffv1" if ffv1_ok else "png1")
    mdl = motion.model
    poses = [forward(mdl, p) for p in motion.params]
    if isinstance(cameras, int):
        pts = np.concatenate([body_points(mdl, pose, n_theta=8, n_z=2).reshape(-1, 3) for pose in poses])
        cams = fit_ring_cameras(pts, cameras, size=tuple(size))
    else:
        cams = list(cameras)
    rng = np.random.default_rng(seed)
    default_palette = make_palette(mdl, rng)  # drawn either way: the same noise for a given seed
    palette = default_palette if palette is None else palette
    reach = max(np.linalg.norm(c.center[:2]) for c in cams)
    texture = make_room_texture(seed, wall_radius_m=max(7.0, reach + 2.0), extent_m=max(8.0, reach + 3.0))
    rendered = [render_background(c, texture, with_floor_mask=True) for c in cams]
    backgrounds = [b for b, _ in rendered]
    floors = [f.astype(np.float32) for _, f in rendered]

    save_calibration(out / "calibration.toml", cams)
    sinks = [_Sink(out, c.name, codec, motion.fps, c.size) for c in cams]
    bg_sinks = [_Sink(out, f"background/{c.name}", bg_codec, motion.fps, c.size) for c in cams]
    try:
        for _ in range(n_background if bg_codec != "png1" else 1):
            for s, bg in zip(bg_sinks, backgrounds):
                s.write(_add_noise(bg, noise, rng))
    finally:
        for s in bg_sinks:
            s.close()
    for s in bg_sinks:
        s.check()
    write_session_toml(
        out,
        name=name or Path(str(bvh_path)).stem,
        fps=motion.fps,
        cameras=[{"name": c.name, ("images" if codec == "png" else "video"): s.rel, "background": b.rel}
                 for c, s, b in zip(cams, sinks, bg_sinks)],  # fmt: skip
        height_m=motion.height_m,
        segment_lengths=motion.segment_lengths or None,
    )
    mask_dirs = []
    if masks:
        for c in cams:
            (out / "masks" / c.name).mkdir(parents=True, exist_ok=True)
            mask_dirs.append(out / "masks" / c.name)
    try:
        with open(out / "ground_truth.jsonl", "w") as gt:
            for k, (params, pose) in enumerate(zip(motion.params, poses)):
                images, labels = render_frame(mdl, pose, cams, backgrounds, floors, palette, shadow=shadow)
                for s, img in zip(sinks, images):
                    s.write(_add_noise(img, noise, rng))
                for d, lab in zip(mask_dirs, labels):
                    if not cv2.imwrite(str(d / f"{k:06d}.png"), np.where(lab >= 0, 255, 0).astype(np.uint8)):
                        raise OSError(f"cannot write {d / f'{k:06d}.png'}")
                joints = joint_centre_array(mdl, pose)
                record = {
                    "frame": k,
                    "timestamp_ns": int(round(k * 1e9 / motion.fps)),
                    "ok": True,
                    "model": mdl.name,
                    "params": [float(v) for v in params],
                    "joints": {n: [float(v) for v in joints[i]] for i, n in enumerate(mdl.joint_names)},
                    "height_m": float(motion.height_m),
                }
                gt.write(json.dumps(record) + "\n")
                if progress is not None:
                    progress(k + 1, motion.n_frames)
    finally:
        for s in sinks:
            s.close()
    for s in sinks:
        s.check()
    return out
