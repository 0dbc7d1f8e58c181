"""Track a recorded session in one process: background models → segmentation → tracker.

The offline twin of the live pipeline (``contourcap track``).  Per camera a YUV background model
is learned from the session's background video when it has one, else from the temporal median of
up to ``median_frames`` session frames spread over the clip (the person must move); every frame is
segmented with ``segmentation.pipeline.segment_frame`` and each frame set is fitted by
``tracker.fitting.tracking.Tracker``.  Yields one DESIGN.md pose record per frame id.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterator, Sequence

import numpy as np

from capture.replay import iter_frame_sets, read_frames
from capture.session import Session, SessionError
from segmentation.background import BackgroundModel
from segmentation.pipeline import SegmentationParams, segment_frame
from tracker.body.model import BodyModel, load_model
from tracker.fitting.hypotheses import FrontBackOptions
from tracker.fitting.tracking import Tracker, TrackerOptions

__all__ = ["background_models", "session_model", "track_session", "summarise", "TrackSummary"]


def session_model(session: Session, name: str = "knossow40") -> BodyModel:
    """The body model sized by the session's ``[subject]`` (height, segment lengths)."""
    return load_model(name, height_m=session.height_m, segment_lengths=session.segment_lengths)


def _check_cameras(session: Session, cameras: Sequence[str] | None) -> list[str]:
    names = list(session.camera_names if cameras is None else cameras)
    unknown = [n for n in names if n not in session.camera_names]
    if unknown:
        raise SessionError(f"{session.root}: no camera(s) {unknown} (have {list(session.camera_names)})")
    if not names:
        raise SessionError(f"{session.root}: no camera selected")
    return names


def background_models(session: Session, cameras: Sequence[str], *, frames: range | None = None,
                      median_frames: int = 25) -> tuple[dict[str, BackgroundModel], dict[str, str]]:
    """One background model per camera and how each was made (``"video"`` or ``"median"``)."""
    models, how = {}, {}
    for name in cameras:
        cam = session.camera(name)
        if cam.background is not None:
            models[name] = BackgroundModel.from_frames(f.image for f in read_frames(session, name, background=True))
            how[name] = "video"
            continue
        # keep an evenly strided subset while reading (never the whole clip in memory)
        images, stride = [], 1
        for i, f in enumerate(read_frames(session, name, frames=frames)):
            if i % stride == 0:
                images.append(f.image)
            if len(images) >= 2 * median_frames:
                images, stride = images[::2], stride * 2
        if len(images) < 3:
            raise SessionError(f"{session.root}: camera {name!r} has no background video and only "
                               f"{len(images)} frame(s), too few for a median background")
        pick = np.unique(np.linspace(0, len(images) - 1, min(median_frames, len(images))).round().astype(int))
        models[name] = BackgroundModel.from_median([images[i] for i in pick])
        how[name] = "median"
    return models, how


def track_session(session: Session, *, model: str | BodyModel = "knossow40", sliding: bool = True,
                  solver: str = "lm", frames: range | None = None, cameras: Sequence[str] | None = None,
                  initial_params=None, options: TrackerOptions = TrackerOptions(),
                  segmentation: SegmentationParams | None = None,
                  backgrounds: dict[str, BackgroundModel] | None = None,
                  clock: Callable[[], float] = time.perf_counter, colour: bool = True,
                  front_back: FrontBackOptions | None = FrontBackOptions()) -> Iterator[dict]:
    """Pose records (dicts) for every frame set of ``session`` in frame-id order.

    ``frames``: range of frame ids (None: all); ``cameras``: names to use (None: all);
    ``initial_params``: start pose (n_params,), else automatic initialisation
    (``tracker.search.initialise``) on the first frame.  ``backgrounds`` skips learning them.
    ``colour``: give the tracker the frames' colour images (its front/back appearance cue);
    ``front_back``: the tracker's front/back guard (``tracker.fitting.hypotheses``; None: off).
    """
    names = _check_cameras(session, cameras)
    body = model if isinstance(model, BodyModel) else session_model(session, model)
    cams = [session.camera_model(n) for n in names]
    if backgrounds is None:
        backgrounds, _ = background_models(session, names, frames=frames)
    tracker = Tracker(body, cams, sliding=sliding, solver=solver, initial_params=initial_params,
                      options=options, clock=clock, front_back=front_back)
    for fid, group in iter_frame_sets(session, cameras=names, frames=frames):
        segs = {n: segment_frame(backgrounds[n], f.image, params=segmentation) for n, f in group.items()}
        ts = next(iter(group.values())).timestamp_ns
        yield tracker.step(fid, ts, {n: s.chamfer for n, s in segs.items()},
                           silhouettes={n: s.silhouette for n, s in segs.items()},
                           images={n: f.image for n, f in group.items()} if colour else None)


@dataclass(frozen=True)
class TrackSummary:
    """frames, ok, lost : counts; median_iterations, median_rms_px : over ok frames (NaN if none);
    fps : frames per second of wall time."""

    frames: int
    ok: int
    lost: int
    median_iterations: float
    median_rms_px: float
    fps: float

    def as_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


def summarise(records: Sequence[dict], elapsed_s: float) -> TrackSummary:
    ok = [r for r in records if r.get("ok")]
    its = [r["iterations"] for r in ok]
    rms = [r["rms_px"] for r in ok if r.get("rms_px") is not None]
    return TrackSummary(len(records), len(ok), len(records) - len(ok),
                        float(np.median(its)) if its else float("nan"),
                        float(np.median(rms)) if rms else float("nan"),
                        len(records) / elapsed_s if elapsed_s > 0 else float("nan"))
