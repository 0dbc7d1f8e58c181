"""The background model of a session's camera: one rule for ``contourcap segment``, ``track`` and the workers."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from capture.replay import read_frames
from capture.session import Session, SessionError
from segmentation.background import BackgroundModel, bgr_to_yuv, evenly_spaced

__all__ = ["LearntBackground", "learn_background", "background_models"]


@dataclass(frozen=True)
class LearntBackground:
    """A camera's background model and what it was learnt from.

    Attributes
    ----------
    model : BackgroundModel
    source : {"video", "image", "median"}
        Background media frames, a single background image, or a median of session frames.
    frames : int
        How many frames went into it.
    """

    model: BackgroundModel
    source: str
    frames: int

    def describe(self) -> str:
        """``"background media (N frames)"``, ``"background image"`` or ``"median of N session frames"``."""
        return {"video": f"background media ({self.frames} frames)", "image": "background image",
                "median": f"median of {self.frames} session frames"}[self.source]


def learn_background(session: Session, camera: str, *, background_frames: int | None = None,
                     median_frames: int = 25, covariance: str = "diag",
                     frames: range | None = None) -> LearntBackground:
    """Learn one camera's background model from its session.

    From the camera's background media when it has some: a video's frames (mean and covariance),
    or a single image (its variances are the model's floor).  Otherwise the temporal median of
    about ``median_frames`` session frames spread over the clip (the person must move).

    Parameters
    ----------
    session : Session
    camera : str
        Camera name.
    background_frames : int or None
        Use at most this many background-media frames (None: all).
    median_frames : int
        Session frames for a median background (>= 3 are needed).
    covariance : {"diag", "full"}
        Covariance of a model learnt from background media.
    frames : range or None
        Frame ids the median is taken over (None: the whole session).

    Returns
    -------
    LearntBackground

    Raises
    ------
    SessionError
        Empty background media, or too few session frames for a median.
    """
    if background_frames is not None and background_frames < 1:
        raise ValueError(f"background_frames: expected >= 1, got {background_frames}")
    cam = session.camera(camera)
    if cam.background is not None:
        images = []
        for f in read_frames(session, camera, background=True):
            images.append(f.image)
            if background_frames is not None and len(images) >= background_frames:
                break
        if len(images) == 1:  # a single background image: the variances are the model's floor
            model = BackgroundModel(bgr_to_yuv(images[0]), np.zeros(images[0].shape[:2] + (6,), np.float32),
                                    covariance=covariance)
            return LearntBackground(model, "image", 1)
        if not images:
            raise SessionError(f"{cam.background}: camera {camera!r}: background media has no frames")
        return LearntBackground(BackgroundModel.from_frames(images, covariance=covariance), "video", len(images))
    images = evenly_spaced((f.image for f in read_frames(session, camera, frames=frames)), median_frames)
    if len(images) < 3:
        raise SessionError(f"{session.root}: camera {camera!r} has no background media and only "
                           f"{len(images)} frame(s), too few for a median background")
    return LearntBackground(BackgroundModel.from_median(images), "median", len(images))


def background_models(session: Session, cameras: Sequence[str], *, frames: range | None = None,
                      median_frames: int = 25) -> tuple[dict[str, BackgroundModel], dict[str, str]]:
    """:func:`learn_background` of every camera, from all its background media.

    Returns
    -------
    models : dict
        Camera name -> BackgroundModel.
    how : dict
        Camera name -> ``LearntBackground.source`` (``"video"``, ``"image"`` or ``"median"``).
    """
    learnt = {name: learn_background(session, name, median_frames=median_frames, frames=frames) for name in cameras}
    return {n: b.model for n, b in learnt.items()}, {n: b.source for n, b in learnt.items()}
