"""Track a recorded session in one process: background models → segmentation → tracker.

The offline twin of the live pipeline (``contourcap track``).  Per camera a YUV background model
is learned by :func:`service.backgrounds.learn_background` (background media, else a temporal
median of session frames); every frame is
segmented with ``segmentation.pipeline.segment_frame`` and each frame set is fitted by
``tracker.fitting.tracking.Tracker``.  Unlike a live tracker it can look ahead: the frames of a stretch
the gate refused are fitted again backwards from the first accepted frame after it (``settled_records``).
Yields one DESIGN.md pose record per frame id.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Mapping, Sequence

import numpy as np

from capture.media import StreamCheck
from capture.replay import iter_frame_sets
from capture.session import Session, SessionError
from segmentation.background import BackgroundModel
from segmentation.floor import FloorShadows
from segmentation.pipeline import SegmentationParams, segment_frame
from service.backgrounds import background_models
from service.smoothed import SMOOTH_WINDOW_S, smoothed_records, window_half
from tracker.body.model import BodyModel, load_model
from tracker.fitting.hypotheses import FrontBackOptions
from tracker.fitting.scene import SceneOptions, SceneTracker
from tracker.fitting.tracking import Tracker, TrackerOptions
from tracker.fitting.uncovered import fit_ok

__all__ = ["background_models", "floor_test", "warm_up_kernels", "session_model", "session_props", "settled_records",
           "refit_kept", "track_session", "summarise", "ImageTracker", "TrackSummary", "MAX_HELD_FRAMES",
           "MAX_HELD_BYTES"]


def session_model(session: Session, name: str = "knossow40") -> BodyModel:
    """The body model sized by the session's ``[subject]`` (its subject file when it names one and
    the model is the file's, else height and segment lengths)."""
    if session.subject_file is not None:
        from tracker.body.subject import read_subject

        subject = read_subject(session.subject_file)
        if subject.model == name:
            return subject.body()
    return load_model(name, height_m=session.height_m, segment_lengths=session.segment_lengths)


def session_props(session: Session) -> list:
    """The session's ``[[prop]]`` boxes as ``tracker.fitting.props.PropBox`` (world metres, never body;
    ``hollow = true``: ``solid`` False)."""
    from tracker.fitting.props import PropBox

    hollow = session.hollow_props or (False,) * len(session.props)
    return [PropBox.from_values(b, where=f"{session.root / 'session.toml'} [[prop]]", solid=not h)
            for b, h in zip(session.props, hollow)]


def warm_up_kernels(method: str = "contours") -> float:
    """Compile (first run) or load from numba's on-disk cache the kernels a ``method`` fit runs: the
    contour tracker's and the sampled background and floor tests' (``segmentation.samples``), and for
    ``"blobs"`` also the blob tracker's (its first pose is the contour tracker's); seconds taken."""
    from segmentation.samples import warm_up as warm_samples
    from tracker.fitting.warmup import warm_up as warm_contours

    t0 = time.perf_counter()
    warm_samples()
    if method == "blobs":
        from tracker.blobs.kernels import warm_up as warm_blobs

        warm_blobs()
    warm_contours()
    return time.perf_counter() - t0


def floor_test(cameras, backgrounds: dict[str, BackgroundModel],
               params: SegmentationParams | None = None) -> FloorShadows | None:
    """The multi-view floor test of shadow-like pixels (``segmentation.floor``) for these cameras,
    or None when ``params.floor_test`` is off or there is only one camera."""
    params = params or SegmentationParams()
    if not params.floor_test or len(cameras) < 2:
        return None
    return FloorShadows(cameras, backgrounds, low=params.low)


def _frame_sets(session: Session, cameras, frames, stream_check) -> Iterator[tuple[int, dict]]:
    """``iter_frame_sets`` with every set shown to ``stream_check`` (when given) first."""
    for fid, group in iter_frame_sets(session, cameras=cameras, frames=frames):
        if stream_check is not None:
            stream_check.see(fid, tuple(group))
        yield fid, group


def _check_cameras(session: Session, cameras: Sequence[str] | None) -> list[str]:
    names = list(session.camera_names if cameras is None else cameras)
    unknown = [n for n in names if n not in session.camera_names]
    if unknown:
        raise SessionError(f"{session.root}: no camera(s) {unknown} (have {list(session.camera_names)})")
    if not names:
        raise SessionError(f"{session.root}: no camera selected")
    return names


def track_session(session: Session, *, model: str | BodyModel = "knossow40", sliding: bool = True,
                  solver: str = "lm", frames: range | None = None, cameras: Sequence[str] | None = None,
                  initial_params=None, options: TrackerOptions = TrackerOptions(),
                  segmentation: SegmentationParams | None = None,
                  backgrounds: dict[str, BackgroundModel] | None = None,
                  clock: Callable[[], float] = time.perf_counter, method: str = "contours",
                  blob_options=None, scene: SceneOptions | None = None,
                  ignore: dict[str, np.ndarray] | None = None, colour: bool = True,
                  front_back: FrontBackOptions | None = FrontBackOptions(),
                  stream_check: StreamCheck | None = None, props=None, retrack: bool = True,
                  smooth_s: float | None = None, stop: Callable[[], bool] | None = None,
                  on_step: Callable[[dict], None] | None = None) -> Iterator[dict]:
    """Pose records for every frame set of ``session``, in frame-id order.

    Parameters
    ----------
    session : Session
    model : str or BodyModel, the body model (a name is sized by the session's subject)
    sliding, solver, options, segmentation
        Contour tracker settings (``tracker.fitting.tracking.Tracker``, ``SegmentationParams``).
    frames, cameras : range or None, sequence of str or None; frame ids, camera names (None: all)
    initial_params : ndarray, shape (n_params,), optional, the start pose (None: automatic initialisation)
    backgrounds : dict, optional, camera name -> BackgroundModel (None: ``service.backgrounds``)
    clock : callable () -> float, seconds for the tracker's timings
    method : {"contours", "blobs"}, ``tracker.fitting.Tracker`` or ``tracker.blobs.BlobTracker`` (``blob_options``)
    scene : SceneOptions, optional, contours only: decide which foreground is body (``tracker.fitting.scene``)
    ignore : dict, optional, camera name -> (h, w) bool mask of pixels never body (with ``scene``)
    colour, front_back : bool, FrontBackOptions or None
        Frame colours for, and options of, the front/back guard (``tracker.fitting.hypotheses``).
    stream_check : StreamCheck, optional, sees each frame set (names a camera cut short)
    props : sequence of PropBox, optional, world boxes never body (with ``scene``, or blobs; ``tracker.fitting.props``)
    retrack, stop : bool, callable () -> bool or None; contours: fit a scene's warm-up frames and every refused
        stretch again backwards from the next accepted frame (``settled_records``, at most ``MAX_HELD_BYTES`` of
        images held; False: every frame once, as live); ``stop()`` (both methods), asked before each set, True
        ends the records; contours: ``on_step(record)`` sees each set's first fit as it is made
    smooth_s : float or None, seconds; the poses smoothed over a centred window that long (``service.smoothed``; 0: as
        fitted; None: ``SMOOTH_WINDOW_S``, or 0 without ``retrack``: as live)

    Yields
    ------
    dict, a DESIGN.md pose record per frame id
    """
    if method not in ("contours", "blobs"):
        raise ValueError(f"method: expected 'contours' or 'blobs', got {method!r}")
    names = _check_cameras(session, cameras)
    body = model if isinstance(model, BodyModel) else session_model(session, model)
    cams = [session.camera_model(n) for n in names]
    if backgrounds is None:
        backgrounds, _ = background_models(session, names, frames=frames)
    half = window_half((SMOOTH_WINDOW_S if retrack else 0.0) if smooth_s is None else smooth_s, session.fps)
    if method == "blobs":
        yield from _smoothed(_track_blobs(session, body, cams, backgrounds, frames, initial_params, blob_options,
                                          clock, stream_check, props=props, stop=stop), body, half, session.fps)
        return
    tracker = Tracker(body, cams, sliding=sliding, solver=solver, initial_params=initial_params,
                      options=options, clock=clock, front_back=front_back)

    def read(fids, check):
        return ((fid, next(iter(group.values())).timestamp_ns, {n: f.image for n, f in group.items()})
                for fid, group in _frame_sets(session, names, fids, check))

    floor = floor_test(cams, backgrounds, segmentation)
    ours = {n: backgrounds[n] for n in names}
    st = (SceneTracker(tracker, ours, ignore=ignore, options=scene, segmentation=segmentation, floor=floor, props=props)
          if scene is not None else ImageTracker(tracker, ours, segmentation=segmentation, floor=floor, colour=colour))
    per_set = sum(3 * c.width * c.height for c in cams)
    held = max(1, min(MAX_HELD_FRAMES, MAX_HELD_BYTES // per_set)) if retrack else 0
    yield from _smoothed(settled_records(st, read(frames, stream_check), max_held=held, stop=stop, on_step=on_step),
                         body, half, session.fps)


def _smoothed(records: Iterator[dict], body: BodyModel, half: int, fps: float) -> Iterator[dict]:
    return smoothed_records(records, body, half=half, fps=fps) if half > 0 else records


class ImageTracker:
    """A ``Tracker`` fed with images: every camera's frame segmented against its background model (with
    the floor test when given), then fitted; ``track_session``'s path without ``scene``.

    Parameters
    ----------
    tracker : Tracker
    backgrounds : camera name -> BackgroundModel
    segmentation : SegmentationParams or None (the defaults)
    floor : segmentation.floor.FloorShadows or None, the multi-view floor test of shadow-like pixels
    colour : bool, hand the frame's images to the tracker (its front/back guard and limb colour check)

    Attributes
    ----------
    warming : always False (nothing is learned from the scene; ``settled_records`` asks)
    """

    warming = False

    def __init__(self, tracker: Tracker, backgrounds: Mapping[str, BackgroundModel], *,
                 segmentation: SegmentationParams | None = None, floor: FloorShadows | None = None,
                 colour: bool = True) -> None:
        self.tracker, self.backgrounds = tracker, dict(backgrounds)
        self.segmentation, self.floor, self.colour = segmentation, floor, colour

    def step(self, frame_id: int, timestamp_ns: int, images: Mapping[str, np.ndarray]) -> dict:
        """Segment ``images`` (camera name -> BGR uint8 (h, w, 3)) and fit them; the pose record."""
        segs = {n: segment_frame(self.backgrounds[n], img, params=self.segmentation,
                                 floor=None if self.floor is None else self.floor.for_camera(n, images))
                for n, img in images.items()}
        return self.tracker.step(frame_id, timestamp_ns, {n: s.chamfer for n, s in segs.items()},
                                 silhouettes={n: s.silhouette for n, s in segs.items()},
                                 images=dict(images) if self.colour else None)

    def retrack(self, frames: Iterable[tuple[int, int, Mapping[str, np.ndarray]]]) -> list[dict]:
        """Fit ``frames`` (frame id, timestamp ns, camera name -> BGR image) again, in the order given,
        from this tracker's state on a copy (``Tracker.twin``); their pose records in that order."""
        twin = ImageTracker(self.tracker.twin(), self.backgrounds, segmentation=self.segmentation,
                            floor=self.floor, colour=self.colour)
        return [twin.step(*item) for item in frames]


#: at most this many frames are held for a refit (``settled_records``): older ones keep their first records
MAX_HELD_FRAMES = 150
#: ``track_session`` holds the images of at most this many bytes of frame sets for a refit
MAX_HELD_BYTES = 1 << 30


def settled_records(st: "SceneTracker | ImageTracker", sets: Iterable[tuple[int, int, Mapping[str, np.ndarray]]],
                    *, refused: bool = True, max_held: int = MAX_HELD_FRAMES, stop: Callable[[], bool] | None = None,
                    on_step: Callable[[dict], None] | None = None, tail: bool = True) -> Iterator[dict]:
    """``st``'s pose records for ``sets`` (frame id, timestamp ns, camera name -> BGR image), in order,
    the frames of each warm-up and of each refused stretch fitted again backwards once the track is past them.

    ``st`` has ``step``, ``warming`` and ``retrack``.  A frame is held, with its images and record, while
    ``st.warming`` (a scene's warm-up: reverse term off, clutter not yet learned) and, with ``refused``,
    while the gate refuses its fit (``fit_ok``: the unexplained-boundary check alone only reports; a lost
    stretch the track found its way out of later); at the next frame that is neither, ``st.retrack`` fits
    the held frames again latest first from that frame's state, and a held frame's record is the refit's,
    marked ``"refit": true``, when ``refit_kept``, else the first fit's.  At most ``max_held`` frames are
    held (the oldest leave with their first records; 0: every frame once, as live).  With ``tail``, the
    frames still held when ``sets`` ends (a take that ends refused, or never reached an accepted frame) are
    fitted again the same way from the last frame's state, unless ``stop()`` says so; frames held when
    ``stop()`` (asked before each frame) ends the run, or when an exception (an interrupt) leaves the loop,
    keep their first records, yielded before the exception goes on.  ``on_step(record)`` sees every first
    fit as it is made (progress while frames are held).
    """
    held: list[tuple[tuple, dict]] = []
    stopped = False
    try:
        for item in sets:
            if stop is not None and stop():
                stopped = True
                break
            rec = st.step(*item)
            if on_step is not None:
                on_step(rec)
            if st.warming or (refused and not fit_ok(rec)):
                held.append((item, rec))
                if len(held) > max_held:
                    yield held.pop(0)[1]
                continue
            if held:  # the accepted frame waits with them: an interrupt in the refit writes it too
                held.append((item, rec))
                kept, held = _refitted(st, held[:-1]) + [rec], []
                yield from kept
                continue
            yield rec
        if held and tail and not stopped and not (stop is not None and stop()):
            kept, held = _refitted(st, held), []
            yield from kept
    except (Exception, KeyboardInterrupt):
        out, held = held, []
        yield from (r for _, r in out)
        raise
    yield from (r for _, r in held)


def _refitted(st, held: list) -> list[dict]:
    """``held`` (item, first record) fitted again latest first by ``st.retrack``; each frame's kept record,
    in ``held``'s order."""
    refits = {r["frame"]: r for r in st.retrack([it for it, _ in reversed(held)])}
    return [{**refits[it[0]], "refit": True} if it[0] in refits and refit_kept(refits[it[0]], first) else first
            for it, first in held]


def refit_kept(refit: dict, first: dict) -> bool:
    """Whether ``settled_records`` keeps a held frame's refit (pose record ``refit``) over its first fit
    (``first``): the refit has a pose and passed the gate (``tracker.fitting.uncovered.fit_ok``: it is ok,
    or refused only by the unexplained-boundary check), or neither passed and the refit's silhouette IoU
    is at least the first fit's (the refit when either has none).

    The unexplained-boundary check weighs a fit against the track's recent shares of unexplained
    boundary, with the reverse term on: a first fit of a scene's warm-up (reverse term off) can never
    fail it, so it cannot choose between the two fits; it only reports, and a refit it refuses is kept
    with its record saying why it is not ok.
    """
    if "params" not in refit:
        return False
    if fit_ok(refit) or fit_ok(first):
        return fit_ok(refit)
    a, b = first.get("iou"), refit.get("iou")
    return a is None or b is None or b >= a


def _track_blobs(session, body, cams, backgrounds, frames, initial_params, blob_options, clock,
                 stream_check=None, props=None, stop=None) -> Iterator[dict]:
    from tracker.blobs import BlobOptions, BlobTracker
    from tracker.blobs.start import ContourStart

    tracker = BlobTracker(body, cams, backgrounds, initial_params=initial_params,
                          initialiser=ContourStart(body, cams, backgrounds, props=props or ()),
                          options=blob_options or BlobOptions(), clock=clock, props=props or ())
    for fid, group in _frame_sets(session, [c.name for c in cams], frames, stream_check):
        if stop is not None and stop():
            return
        ts = next(iter(group.values())).timestamp_ns
        yield tracker.step(fid, ts, {n: f.image for n, f in group.items()})


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
        """The fields as a JSON-ready dict (NaN as None)."""
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


def summarise(records: Sequence[dict], elapsed_s: float) -> TrackSummary:
    """Counts and medians of pose records (``ok``, ``iterations``, ``rms_px`` keys) tracked in ``elapsed_s`` seconds."""
    ok = [r for r in records if r.get("ok")]
    its = [r["iterations"] for r in ok]
    rms = [r["rms_px"] for r in ok if r.get("rms_px") is not None]
    return TrackSummary(len(records), len(ok), len(records) - len(ok),
                        float(np.median(its)) if its else float("nan"),
                        float(np.median(rms)) if rms else float("nan"),
                        len(records) / elapsed_s if elapsed_s > 0 else float("nan"))
