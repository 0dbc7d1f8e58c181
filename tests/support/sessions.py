"""Tiny synthetic session directories for the capture tests (written into tmp_path).

``make_session`` writes FFV1 videos (lossless here) or PNG sequences of seeded random images, optional
timestamp CSVs with dropped frames, and a look-at calibration.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from capture.calibration import save_calibration
from capture.camera import Camera
from capture.session import Session, load_session, write_session_toml

SIZE = (64, 48)  # width, height


def make_images(rng: np.random.Generator, n: int, size=SIZE) -> list[np.ndarray]:
    """``n`` random BGR images, each shape (h, w, 3) uint8, with a frame-number stripe."""
    w, h = size
    out = []
    for k in range(n):
        img = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        img[:4, :] = k % 256
        out.append(img)
    return out


def write_video(path: Path, images, fps: float = 25.0, fourcc: str = "FFV1") -> Path:
    h, w = images[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened(), f"cannot write {fourcc} video {path}"
    for img in images:
        writer.write(img)
    writer.release()
    return path


def make_session(
    root: Path,
    rng: np.random.Generator,
    *,
    cams=("cam0", "cam1"),
    n_frames: int = 10,
    fps: float = 25.0,
    kind: str = "video",
    drops: dict | None = None,
    csv: bool = False,
    background: bool = False,
) -> tuple[Session, dict[str, dict[int, np.ndarray]]]:
    """Write a session; returns it and the expected images ``{camera: {frame_id: image}}``.

    ``drops`` maps a camera to frame ids it did not store (needs ``csv=True``
    for videos; for image sequences the missing file is the drop).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    drops = drops or {}
    entries, expected, calib = [], {}, []
    for i, name in enumerate(cams):
        ids = [k for k in range(n_frames) if k not in set(drops.get(name, ()))]
        images = make_images(rng, len(ids))
        expected[name] = dict(zip(ids, images))
        entry = {"name": name}
        if kind == "video":
            write_video(root / f"{name}.avi", images, fps)
            entry["video"] = f"{name}.avi"
        else:
            (root / name).mkdir(exist_ok=True)
            for fid, img in zip(ids, images):
                cv2.imwrite(str(root / name / f"{fid:06d}.png"), img)
            entry["images"] = f"{name}/%06d.png"
        if csv:
            lines = ["frame_id,timestamp_ns"] + [f"{fid},{1_000_000_000 + int(round(fid * 1e9 / fps)) + 7}" for fid in ids]
            (root / f"{name}.csv").write_text("\n".join(lines) + "\n")
            entry["timestamps"] = f"{name}.csv"
        if background:
            (root / "background").mkdir(exist_ok=True)
            write_video(root / "background" / f"{name}.avi", make_images(rng, 3), fps)
            entry["background"] = f"background/{name}.avi"
        entries.append(entry)
        angle = 2 * np.pi * i / max(len(cams), 1)
        eye = (3 * np.cos(angle), 3 * np.sin(angle), 1.5)
        calib.append(Camera.look_at(name, eye, (0, 0, 1), size=SIZE))
    write_session_toml(root, name="synthetic", fps=fps, cameras=entries, height_m=1.7)
    save_calibration(root / "calibration.toml", calib)
    return load_session(root), expected

