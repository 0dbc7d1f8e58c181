"""Writing a synthetic session directory from BVH motion (the rendering is ``tracker.synthetic.synth``).

``make_synthetic_session(bvh_path, out_dir, ...)`` writes a DESIGN.md session directory::

    OUT/
      session.toml          [session] name, fps; [subject] height_m (+ segment_lengths
                            with fit_segments); [[camera]] name, video|images, background
      calibration.toml      capture.calibration.save_calibration (anipose layout)
      cam0.avi …            frame k = trigger pulse k (FFV1 by default: lossless)
      background/cam0.avi … the empty room, ``n_background`` frames, same noise
      ground_truth.jsonl    one DESIGN.md pose record per frame (frame, timestamp_ns, ok,
                            model, params, joints {name: [x, y, z]}, height_m)
      masks/cam0/000000.png true silhouettes (255 = body), with ``masks=True``
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from capture.calibration import save_calibration
from capture.camera import Camera
from capture.session import write_session_toml
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.retarget import Retargeted, retarget_bvh
from tracker.synthetic.synth import Palette, add_noise, ground_truth_record, synthetic_studio

__all__ = ["make_synthetic_session", "make_proportioned_session", "CODECS"]

CODECS = ("ffv1", "png", "mjpg")
_FOURCC = {"ffv1": "FFV1", "mjpg": "MJPG"}


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
        The subject's colours (default: drawn from ``seed``, ``tracker.synthetic.synth.make_palette``).
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
    rng = np.random.default_rng(seed)
    studio = synthetic_studio(motion, cameras=cameras, size=size, seed=seed, rng=rng, palette=palette)
    cams, backgrounds = studio.cameras, studio.backgrounds

    save_calibration(out / "calibration.toml", cams)
    sinks = [_Sink(out, c.name, codec, motion.fps, c.size) for c in cams]
    bg_sinks = [_Sink(out, f"background/{c.name}", bg_codec, motion.fps, c.size) for c in cams]
    try:
        for _ in range(n_background if bg_codec != "png1" else 1):
            for s, bg in zip(bg_sinks, backgrounds):
                s.write(add_noise(bg, noise, rng))
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
            for k, pose in enumerate(studio.poses):
                images, labels = studio.render(k, shadow=shadow)
                for s, img in zip(sinks, images):
                    s.write(add_noise(img, noise, rng))
                for d, lab in zip(mask_dirs, labels):
                    if not cv2.imwrite(str(d / f"{k:06d}.png"), np.where(lab >= 0, 255, 0).astype(np.uint8)):
                        raise OSError(f"cannot write {d / f'{k:06d}.png'}")
                gt.write(json.dumps(ground_truth_record(motion, k, pose)) + "\n")
                if progress is not None:
                    progress(k + 1, motion.n_frames)
    finally:
        for s in sinks:
            s.close()
    for s in sinks:
        s.check()
    return out


def make_proportioned_session(out_dir, *, seed: int = 0, spread: float = 0.15, frames: int = 120,
                              motion: str = "scaled_131_03", **options) -> tuple[Path, dict]:
    """A synthetic session of a body whose segment lengths are drawn within ``±spread`` of the model's
    anthropometric ones (seeded), moving as ``motion`` (a bundled BVH); session.toml gives the height
    only, so a tracker starts from the model's default proportions.  ``options``: as
    :func:`make_synthetic_session`.  Returns ``(out_dir, true segment lengths in metres)``."""
    from dataclasses import replace

    from tracker.body.model import load_model
    from tracker.fitting.subject_size import nominal_segment_lengths
    from tracker.synthetic.synth import bundled_motion

    base = retarget_bvh(load_bvh(bundled_motion(motion)), fps=options.get("fps", 30.0), frames=frames)
    rng = np.random.default_rng(seed)
    true = {k: v * float(rng.uniform(1 - spread, 1 + spread)) for k, v in nominal_segment_lengths(base.model).items()}
    body = load_model(base.model.name, height_m=base.height_m, segment_lengths=true)
    return make_synthetic_session(bundled_motion(motion), out_dir, retargeted=replace(base, model=body), seed=seed,
                                  **options), true
