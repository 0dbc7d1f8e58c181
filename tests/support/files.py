"""Reading back what contourcap wrote: JSON-lines records and every frame of a video."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np


def read_jsonl(path: Path) -> list[dict]:
    """Every JSON object of a JSON-lines file (blank lines skipped)."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def read_video(path: Path) -> list[np.ndarray]:
    """Every frame of a video, BGR uint8 (h, w, 3)."""
    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(img)
    cap.release()
    return frames
