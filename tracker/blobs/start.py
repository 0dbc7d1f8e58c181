"""The blob tracker's first pose from the contour tracker's first frames.

The blobs are learnt from the hull at the first pose, so an error there persists: a body turned
round, or a limb on the wrong side, is learnt as right and tracked self-consistently.  A single
silhouette search cannot always tell front from back; the contour tracker's front/back guard
(``tracker.fitting.hypotheses``) tracks both hypotheses over several frames and settles the
question from the fit, the feet, the head and the colours.  :class:`ContourStart` runs the contour
tracker (segmentation with the multi-view floor test, ``tracker.fitting.tracking.Tracker``) on the
first frame sets, reports its poses meanwhile, and hands its pose over once the guard has settled
front/back on an ok frame, or after ``max_frames`` frame sets in any case.  With the operator's props
(a chair), the contour tracker runs inside ``tracker.fitting.scene.SceneTracker``, which cuts them from
the silhouettes and keeps the fit out of them.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from segmentation.background import BackgroundModel
from tracker.body.model import BodyModel

__all__ = ["ContourStart", "StartPending"]


class StartPending(ValueError):
    """The first pose is not settled yet; ``record`` is the contour tracker's pose record of this frame set."""

    def __init__(self, message: str, record: dict) -> None:
        super().__init__(message)
        self.record = record


class ContourStart:
    """A ``BlobTracker`` initialiser (module docstring): ``(cameras, images) -> params``.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera (the studio)
    backgrounds : camera name -> BackgroundModel
    max_frames : int
        Frame sets after which the contour tracker's pose is handed over even if front/back is not settled.
    floor_test : bool
        Segment with the multi-view floor test of shadow-like pixels (two cameras or more).
    props : sequence of ``tracker.fitting.props.PropBox``, world boxes never body

    Raises (when called)
    ------
    StartPending
        While front/back is not settled (its ``record`` holds the contour pose of the frame set).
    ValueError
        When the contour tracker finds no pose at all.
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], backgrounds: Mapping[str, BackgroundModel], *,
                 max_frames: int = 30, floor_test: bool = True, props=()) -> None:
        from segmentation.floor import FloorShadows

        if int(max_frames) < 1:
            raise ValueError(f"max_frames: expected >= 1, got {max_frames!r}")
        self.model, self.cameras = model, list(cameras)
        self.backgrounds = dict(backgrounds)
        self.max_frames = int(max_frames)
        self.props = list(props)
        self.floor = (FloorShadows(self.cameras, {c.name: self.backgrounds[c.name] for c in self.cameras})
                      if floor_test and len(self.cameras) >= 2 else None)
        self.reset()

    def reset(self) -> None:
        """Start again from a silhouette search on the next call."""
        from tracker.fitting.tracking import Tracker

        self.tracker = Tracker(self.model, self.cameras)
        self.scene = None
        if self.props:
            from tracker.fitting.scene import SceneOptions, SceneTracker

            self.scene = SceneTracker(self.tracker, self.backgrounds, options=SceneOptions(), floor=self.floor,
                                      props=self.props)
        self.frames = 0

    def __call__(self, cameras: Sequence[Camera], images: Mapping[str, np.ndarray]) -> np.ndarray:
        from segmentation.pipeline import segment_frame

        names = [c.name for c in cameras if c.name in images]
        if self.scene is not None:
            record = self.scene.step(self.frames, 0, {n: images[n] for n in names})
        else:
            segs = {n: segment_frame(self.backgrounds[n], images[n],
                                     floor=None if self.floor is None else self.floor.for_camera(n, images))
                    for n in names}
            record = self.tracker.step(self.frames, 0, {n: s.chamfer for n, s in segs.items()},
                                       silhouettes={n: s.silhouette for n, s in segs.items()},
                                       images={n: images[n] for n in names})
        self.frames += 1
        if "params" not in record:
            if self.frames >= self.max_frames:
                self.reset()
                raise ValueError(record.get("reason", "no pose"))
            raise StartPending(record.get("reason", "no pose"), record)
        settled = record.get("ok") and record.get("front_back", "resolved") == "resolved"
        if settled or self.frames >= self.max_frames:
            params = self.model.clamp(np.asarray(record["params"], dtype=float))
            self.reset()
            return params
        raise StartPending(f"front/back {record.get('front_back')}, contour fit ok: {record.get('ok')}", record)
