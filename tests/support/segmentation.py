"""Helpers for the segmentation tests: IoU, and reading selected frames of a real video."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def iou(a: np.ndarray, b: np.ndarray) -> float:
    a = a > 0
    b = b > 0
    union = np.count_nonzero(a | b)
    return float(np.count_nonzero(a & b)) / union if union else 1.0


def read_frames(path: Path, indices) -> list[np.ndarray]:
    """BGR frames at the given indices (read sequentially; stops after the last one needed)."""
    wanted = sorted(set(int(i) for i in indices))
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise OSError(f"{path}: cannot open video")
    out, i = [], 0
    try:
        while wanted and i <= wanted[-1]:
            ok, frame = cap.read()
            if not ok:
                break
            if i in wanted:
                out.append(frame)
            i += 1
    finally:
        cap.release()
    if len(out) != len(wanted):
        raise OSError(f"{path}: read {len(out)} of {len(wanted)} frames")
    return out


def frame_count(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.grab():
        n += 1
    cap.release()
    return n
