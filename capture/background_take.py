"""The empty-room take: a background plate recorded with every session (``contourcap record --background``).

Before the take, each camera records ``seconds`` of the empty room into ``background/<camera>.avi``
(FFV1, lossless), which the session lists as the camera's ``background``.  The background models of
``contourcap track`` and the segment workers are then learnt from it (``service.backgrounds``) instead of
a temporal median of the take, which fails for a subject who stays in view (the median of a still
person is the person).  Each file is written to a temporary name and renamed when complete.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from capture.atomic import atomic_path
from capture.recorder import RecorderError
from capture.sources import EndOfStream, SourceError

__all__ = ["BACKGROUND_DIR", "MIN_BACKGROUND_FRAMES", "record_background"]

BACKGROUND_DIR = "background"
MIN_BACKGROUND_FRAMES = 3  # a background model needs a few frames (mean and variance)


def _record_one(src, path: Path, n_frames: int, fps: float, stop: threading.Event) -> int:
    """Read up to ``n_frames`` of ``src`` into the FFV1 video ``path``; returns the frames written."""
    written = 0
    with atomic_path(path) as tmp:
        writer = None
        try:
            with src:
                while written < n_frames and not stop.is_set():
                    try:
                        frame = src.read()
                    except EndOfStream:
                        break
                    image = np.ascontiguousarray(frame.image)
                    if writer is None:
                        size = (image.shape[1], image.shape[0])
                        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"FFV1"), fps, size)
                        if not writer.isOpened():
                            raise RecorderError(f"{path}: cv2.VideoWriter cannot write FFV1")
                    writer.write(image)
                    written += 1
        finally:
            if writer is not None:
                writer.release()
        if written < MIN_BACKGROUND_FRAMES:
            raise RecorderError(f"camera {src.name!r}: only {written} background frame(s) "
                                f"(at least {MIN_BACKGROUND_FRAMES} are needed)")
    return written


def record_background(sources: Sequence, root, *, seconds: float, fps: float,
                      stop: threading.Event | None = None) -> dict[str, str]:
    """Record ``seconds`` of every source (not yet opened, one thread each) as the session's background.

    Parameters
    ----------
    sources : sequence of Source
        One per camera, ``name`` = the camera; each is entered on its thread and closed after.
    root : path
        The session folder; the plates go to ``root/background/<camera>.avi``.
    seconds : float
        Length of the empty-room take (at least ``MIN_BACKGROUND_FRAMES`` frames).
    fps : float
        The cameras' frame rate (frames to record = ceil(seconds * fps)).
    stop : threading.Event, optional
        Ends the take early.

    Returns
    -------
    dict of str to str
        Camera name -> the plate's path relative to ``root`` (the session's ``background`` entry).

    Raises
    ------
    RecorderError
        A camera that delivered fewer than ``MIN_BACKGROUND_FRAMES`` frames or failed (named).
    """
    if not (seconds > 0 and fps > 0):
        raise ValueError(f"background: seconds and fps must be positive, got {seconds}, {fps}")
    root = Path(root)
    (root / BACKGROUND_DIR).mkdir(parents=True, exist_ok=True)
    n_frames = max(MIN_BACKGROUND_FRAMES, math.ceil(seconds * fps))
    stop = threading.Event() if stop is None else stop
    errors: dict[str, str] = {}

    def run(src) -> None:
        try:
            _record_one(src, root / BACKGROUND_DIR / f"{src.name}.avi", n_frames, fps, stop)
        except (RecorderError, SourceError, OSError) as exc:
            errors[src.name] = str(exc)

    threads = [threading.Thread(target=run, args=(s,), name=f"background-{s.name}", daemon=True) for s in sources]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        name = sorted(errors)[0]
        raise RecorderError(f"background take: camera {name!r}: {errors[name]}")
    return {s.name: f"{BACKGROUND_DIR}/{s.name}.avi" for s in sources}
