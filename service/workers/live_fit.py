"""The live track worker's fitter: searches beside tracking, adaptive effort, the next set's ROIs.

:class:`LiveTrackerFitter` wraps :class:`~tracker.fitting.tracking.Tracker` for live delivery
(lossless keeps :class:`~service.workers.components.TrackerFitter`: the same poses as offline):

- **Rejoin at once.**  A poor fit tries the cheap recovery on its own set, in the set's time
  (``tracker.search.recovery.rejoin`` from the last good pose and the fit, a few tens of ms;
  at most every ``rejoin_spacing`` sets): when it finds a pose the set is fitted again from it.
- **Never stall the stream.**  A search from the silhouettes (the first frame's initialisation,
  the recovery once ``patience`` frames in a row were bad: ``rejoin`` again, then the full
  ``recover``) runs beside the worker's loop (a thread: ``search_runner``).  While it searches,
  every set still gets its record at once: during the initialisation ``ok: false`` with
  ``reason`` ``"searching: ..."``; during a recovery the tracker goes on fitting from its
  prediction (a bad fit is ``ok: false``, its reason saying a search runs).  When the search
  ends, the pose found is brought forward through (at most ``catch_up_sets``) sets held while it
  searched; that pose, the search's own and the tracker's prediction are fitted to the next set,
  and the one with the highest silhouette IoU is the tracker's pose from there; a failed search
  is retried.  A search runs only on a set with most cameras' silhouettes.
- **Adaptive effort.**  When fitting a set takes longer than the cameras' frame period the
  tracker falls behind; the fitter then steps down :data:`EFFORT_LEVELS` (fewer contour samples,
  fewer LM iterations, fewer silhouette samples) and steps back up once fits are quick again.
  The level used is the record's optional ``"effort"`` field (DESIGN.md).
- **Where to segment.**  :meth:`LiveTrackerFitter.rois` gives, for a frame about to be demanded,
  each camera's rectangle around the last fitted and the predicted pose
  (``tracker.imaging.roi.pose_rois``), its margin growing with the frames since the last fit; None (whole frames) before the first pose, while
  searching, after a bad frame or when a silhouette touched its ROI's border (``roi_clipped``).
- **The subject's body.**  An ``auto_subject`` (``service.workers.auto_subject``) is offered the good
  sets; its adopted body is taken at a set's start, no search running, and named by the records' ``subject``.
- ``fit_ms``: the time this set's fit took, milliseconds (``latency_ms`` is set by the worker:
  capture to publish); ``rejoin_ms``: of it, the cheap rejoin run in the set's time (only on those sets).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from service.workers.components import TrackerFitter, message_to_chamfer, silhouette_mask
from tracker.fitting.uncovered import fit_ok

__all__ = ["EffortLevel", "EFFORT_LEVELS", "EffortController", "LiveTrackerFitter", "ThreadSearches"]

log = logging.getLogger("contourcap.worker")


@dataclass(frozen=True)
class EffortLevel:
    """One adaptive setting of the fit (``TrackerOptions`` fields it overrides)."""

    level: int
    n_samples: int
    max_iterations: int
    reverse_samples: int

    def as_record(self) -> dict:
        """The pose record's ``effort`` object."""
        return {"level": self.level, "n_samples": self.n_samples, "max_iterations": self.max_iterations,
                "reverse_samples": self.reverse_samples}


EFFORT_LEVELS = (EffortLevel(0, 8, 12, 150), EffortLevel(1, 6, 8, 120), EffortLevel(2, 5, 6, 100))
"""Full effort first (the ``TrackerOptions`` defaults), then cheaper settings."""

LIVE_VELOCITY_DAMPING = 1.0
"""The live tracker's ``TrackerOptions.velocity_damping`` (1: the full constant-velocity step across
the live frame gaps; why less was not adopted: docs/performance.md, "A damped prediction live")."""

LIVE_RESTART_STEP = 0.1
"""The live tracker's ``TrackerOptions.restart_step``: a set whose prediction moves a joint centre more than
this × the body's height from the last fit (or whose fit is suspect) is fitted from the last fit too, the fit
of lower cost kept (None: off; why 0.1: docs/performance.md, "Round 12")."""

REJOIN_ACCEPT_IOU = None
"""Least silhouette IoU of a pose the cheap recovery returns (None: the tracker's own gate,
``TrackerOptions.min_iou``; docs/performance.md compares stricter ones)."""


class EffortController:
    """Chooses the effort level from recent fit times.

    The mean fit time of the last ``window`` fits above ``high`` × the frame period steps down one
    level (cheaper); below ``low`` × the period steps back up; after a change, ``window`` fits are
    waited for before the next.  A bad fit steps back up at once (accuracy before speed: a cheap
    fit that loses the track costs a search).

    Parameters
    ----------
    period_s : float
        The cameras' frame period, seconds.
    levels : int
        Number of levels (0 = full effort).
    high, low : float
        Thresholds as fractions of the period.
    window : int
        Fits averaged (and waited for after a change).
    """

    def __init__(self, period_s: float, *, levels: int = len(EFFORT_LEVELS), high: float = 1.0, low: float = 0.5,
                 window: int = 5) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s: expected > 0, got {period_s!r}")
        self.period_s, self.levels, self.high, self.low = float(period_s), int(levels), float(high), float(low)
        self.window = max(1, int(window))
        self.level = 0
        self._times: list[float] = []

    def update(self, fit_s: float, ok: bool = True) -> int:
        """Take one fit's duration (seconds) and whether it was good; returns the level for the next fit."""
        if not ok:
            self.level, self._times = max(0, self.level - 1), []
            return self.level
        self._times.append(float(fit_s))
        if len(self._times) < self.window:
            return self.level
        mean = float(np.mean(self._times[-self.window:]))
        if mean > self.high * self.period_s and self.level < self.levels - 1:
            self.level += 1
            self._times = []
        elif mean < self.low * self.period_s and self.level > 0:
            self.level -= 1
            self._times = []
        else:
            self._times = self._times[-self.window:]
        return self.level


class ThreadSearches:
    """Runs each search in a daemon thread (the live default): ``start(fn, name, then)``, ``busy()``."""

    def __init__(self) -> None:
        self._thread: threading.Thread | None = None

    def start(self, fn: Callable[[], None], name: str, then: Callable[[], None] | None = None) -> None:
        """Run ``fn()`` then ``then()`` beside the caller (their wall and CPU seconds logged at INFO)."""
        def timed() -> None:
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                result = fn()
                if then is not None:
                    then()
            finally:
                log.info("%s: %.2f s wall, %.2f s CPU", name, time.perf_counter() - w0, time.thread_time() - c0)
            return result

        self._thread = threading.Thread(target=timed, name=name, daemon=True)
        self._thread.start()

    def busy(self) -> bool:
        """Whether the last search still runs."""
        return self._thread is not None and self._thread.is_alive()


class LiveTrackerFitter(TrackerFitter):
    """``(frame_id, timestamp_ns, {camera: ChamferMessage}) -> pose record`` for live delivery
    (module docstring).

    Parameters
    ----------
    tracker : Tracker
        Its own recovery is turned off (``recover = False``): searches run here, in a thread.
    period_s, adaptive : float, bool
        The cameras' frame period, seconds; adapt the effort to it (else always full effort).
    roi_margin_m, roi_margin_per_frame_m, roi_max_margin_m, roi_margin_px : float, float, float, int
        ROI margins: ``roi_margin_m`` + ``roi_margin_per_frame_m`` per frame since the last fit
        (at most ``roi_max_margin_m``), metres, and ``roi_margin_px`` pixels.
    clock, search_runner : callable () -> float, object with ``start(fn, name)`` and ``busy()``
        Seconds (fit times); where searches run (default :class:`ThreadSearches`;
        ``service.live_replay`` runs them at once and holds their result for some sets).
    rejoin_headings, rejoin_accept_iou : int, float or None
        The cheap recovery (``tracker.search.recovery.rejoin``): headings per seed; its pose's least IoU (None: gate's).
    rejoin_spacing, rejoin_beside : int, bool
        A poor fit tries the cheap recovery at once when the last try was at least ``rejoin_spacing`` sets
        ago (-1: never; the search after ``patience`` bad sets remains), in the set's own time (``_rejoin_now``),
        or beside the stream (``rejoin_beside``: no latency spike; its pose taken a few sets later).
    limbs_both, recover_keep, initialise_demand_s, min_search_cameras : bool, int, float, float
        The searches' ``SearchOptions.limb_search_both`` (off: cheaper), the full recovery's ``keep``;
        sets demanded at most every ``initialise_demand_s`` s while initialising (:attr:`demand_interval_s`);
        a search runs only on a set with silhouettes from this fraction of the cameras.
    catch_up_sets, velocity_damping, restart_step, uncovered : int, float, float or None, bool
        Sets held while a search runs, to bring its pose forward through (``_catch_up``; 0: none);
        ``TrackerOptions`` fields live (:data:`LIVE_VELOCITY_DAMPING`, :data:`LIVE_RESTART_STEP`); keep the
        unexplained-boundary check (``uncovered_margin``; off live by default: docs/robustness.md round 17).
    """

    def __init__(self, tracker, *, period_s: float = 1 / 30, adaptive: bool = True, roi_margin_m: float = 0.12,
                 roi_margin_per_frame_m: float = 0.04, roi_max_margin_m: float = 0.40, roi_margin_px: int = 8,
                 clock: Callable[[], float] = time.perf_counter, search_runner=None, rejoin_headings: int = 12,
                 rejoin_spacing: int = 5, rejoin_accept_iou: float | None = REJOIN_ACCEPT_IOU,
                 rejoin_beside: bool = False, limbs_both: bool = False, recover_keep: int = 2,
                 initialise_demand_s: float = 0.2, min_search_cameras: float = 0.75, catch_up_sets: int = 8,
                 velocity_damping: float = LIVE_VELOCITY_DAMPING,
                 restart_step: float | None = LIVE_RESTART_STEP, uncovered: bool = False) -> None:
        super().__init__(tracker)
        tracker.recover = False
        # no extra IoU render on an RMS jump (TrackerOptions.iou_rms_jump) live: replaying live frame-id
        # schedules it found as many ok sets but longer bad runs while searches were held (docs/performance.md)
        # no limb check (TrackerOptions.limb_every) live: its candidate fits run in the set's time and
        # doubled the demo's fitting CPU per set (docs/performance.md)
        opts = tracker.options
        tracker.options = replace(opts, iou_rms_jump=None, limb_every=0, velocity_damping=float(velocity_damping),
                                  restart_step=None if restart_step is None else float(restart_step),
                                  initialise_search=replace(opts.initialise_search, limb_search_both=bool(limbs_both)),
                                  recover_search=replace(opts.recover_search, limb_search_both=bool(limbs_both),
                                                         keep=int(recover_keep)))
        if not uncovered:  # the unexplained-boundary check (TrackerOptions.uncovered_margin) off live
            tracker.options = replace(tracker.options, uncovered_margin=None)  # the tracker drops its watch
        self.base_options = tracker.options
        self.effort = EffortController(period_s, levels=len(EFFORT_LEVELS) if adaptive else 1)
        self.roi_margin_m, self.roi_margin_per_frame_m = float(roi_margin_m), float(roi_margin_per_frame_m)
        self.roi_max_margin_m, self.roi_margin_px = float(roi_max_margin_m), int(roi_margin_px)
        self.clock = clock
        self._lock = threading.Lock()
        self.search_runner = ThreadSearches() if search_runner is None else search_runner
        # (frame id of the pose, the pose brought forward, the search's own pose, the search's refined mirror of
        # the pose brought forward or None); poses None on failure
        self._found: tuple[int, np.ndarray | None, np.ndarray | None, np.ndarray | None] | None = None
        self._last_frame: int | None = None
        self._clipped = False
        self._last_ok = False
        self.searches = self.rejoined = 0
        self.search_kinds: dict[str, int] = {}
        self.rejoin_headings, self.rejoin_accept_iou = int(rejoin_headings), rejoin_accept_iou
        self.rejoin_spacing, self._sets_since_rejoin = int(rejoin_spacing), int(rejoin_spacing)
        self.rejoin_beside = bool(rejoin_beside)
        self.initialise_demand_s = float(initialise_demand_s)
        self.min_search_cameras = float(min_search_cameras)
        self.catch_up_sets = int(catch_up_sets)
        self._held: list[tuple[int, dict]] = []  # (frame id, chamfer images) of sets seen while searching
        #: ``service.workers.auto_subject.AutoSubject`` or None (module docstring); the adopted subject's name
        self.auto_subject, self.subject_name = None, None

    @classmethod
    def from_session(cls, session, *, model: str = "knossow40", initial_params=None, **options) -> "LiveTrackerFitter":
        """A live fitter on ``session``'s calibration and subject (see ``TrackerFitter.from_session``)."""
        base = TrackerFitter.from_session(session, model=model, initial_params=initial_params)
        return cls(base.tracker, period_s=1.0 / float(session.fps or 30.0), **options)

    def warm_up(self) -> float:
        """Compile the tracker's kernels before the first frame (``tracker.fitting.warmup``); seconds."""
        from tracker.fitting.warmup import warm_up

        return warm_up()

    @property
    def searching(self) -> bool:
        """Whether a search runs in the background."""
        return self.search_runner.busy()

    @property
    def demand_interval_s(self) -> float:
        """Least seconds between two demanded sets (``initialise_demand_s`` while the
        initialisation searches, else 0: every set the cameras have)."""
        return self.initialise_demand_s if self.tracker.params is None and self.searching else 0.0

    def _rejoin_accept_iou(self) -> float:
        """Least silhouette IoU of a rejoined pose (``rejoin_accept_iou``, at least the tracker's gate)."""
        gate = self.tracker.options.min_iou
        return gate if self.rejoin_accept_iou is None else max(gate, self.rejoin_accept_iou)

    def _start_search(self, frame_id: int, seeds, images: dict, silhouettes: dict, *, full: bool = True) -> bool:
        """Search from ``silhouettes`` beside the stream (``search_runner``).

        ``seeds`` None: the initialisation.  Else the cheap ``tracker.search.recovery.rejoin`` from
        ``seeds`` (the poses to try, in order) and, when it fails and ``full``, the full ``recover``
        from the first of them.  False when the set has too few cameras (no search)."""
        from tracker.search.initialise import initialise
        from tracker.search.recovery import recover, rejoin

        tr = self.tracker
        names = self._search_cameras(images, silhouettes)
        if not names:
            return False
        cams = [tr.cameras[n] for n in names]
        sils = {n: silhouettes[n] for n in names}
        chs = {n: images[n] for n in names}
        seeds = None if seeds is None else [np.array(p) for p in seeds if p is not None]
        what = "initialisation" if seeds is None else "recovery"

        def run() -> str | None:
            kind = "initialise" if seeds is None else "rejoin"
            try:
                if seeds is None:
                    res = initialise(tr.model, cams, sils, chs, options=tr.options.initialise_search)
                else:
                    res = rejoin(tr.model, cams, sils, chs, seeds, options=tr.options.recover_search,
                                 n_headings=self.rejoin_headings, accept_iou=self._rejoin_accept_iou(),
                                 min_inside_fraction=tr.options.min_inside_fraction)
                    if res is None and full:
                        kind = "full"
                        # the rejoin above was recover's cheap local stage: straight to the full search
                        res = recover(tr.model, cams, sils, chs, seeds[0],
                                      options=replace(tr.options.recover_search, local=False))
                found = None if res is None else tr.model.clamp(np.asarray(res.params, dtype=float))
                mirror = None if res is None else res.clamped_mirror(tr.model)
            except Exception as exc:  # a failed search is retried on the next set
                log.info("%s failed: %s", what, exc)
                found = mirror = None
            with self._lock:
                self._found = (frame_id, found, found, mirror)
            self.search_kinds[kind] = self.search_kinds.get(kind, 0) + 1
            return kind if found is not None else None

        self.searches += 1
        self._held = []
        tr.n_initialisations += 1
        self.search_runner.start(run, f"search-{what}", self._catch_up)
        return True

    def _search_cameras(self, images: dict, silhouettes: dict) -> list[str]:
        """The cameras of this set with a silhouette, or [] when they are fewer than
        ``min_search_cameras`` × the tracker's cameras (a set released before most cameras'
        chamfers came: a search on it finds a pose the full views refute)."""
        names = [n for n in self.tracker.cameras if n in images and np.any(silhouettes[n])]
        return names if len(names) >= self._min_cameras() else []

    def _min_cameras(self) -> int:
        """The least number of cameras a search or a catch-up fit needs (``min_search_cameras``)."""
        return max(1, int(np.ceil(self.min_search_cameras * len(self.tracker.cameras))))

    def _take_found(self, frame_id: int, images: dict, silhouettes: dict) -> None:
        """A finished search's pose (no velocity across it) when it fits this set better.

        The search's pose is of the set it started on; the track went on meanwhile.  The pose was
        brought forward through the sets held while it searched (:meth:`_catch_up`).  The
        tracker's prediction, the pose brought forward and the search's own pose are fitted to
        this set and the one whose fit scores the highest silhouette IoU becomes the tracker's
        pose (the prediction on a tie: the track came back by itself).  As ``Tracker.step`` does with
        its own searches, the front/back question is opened at the pose taken and the search's refined
        mirror of it (brought forward too) offered as the mirror's first start (``FrontBackGuard.offer_mirror``)."""
        from tracker.fitting.tracking import fit_frame
        from tracker.search.scoring import ScoreViews

        with self._lock:
            found, self._found, self._held = self._found, None, []
        if found is None or found[1] is None:
            return
        tr = self.tracker
        start_frame, start, own, mirror = found
        names = [n for n in tr.cameras if n in images and np.any(silhouettes[n])]
        current = tr.predict(frame_id)
        poses = [p for p in (current, start, None if own is start else own) if p is not None]
        if len(poses) > 1 and names:
            cams = [tr.cameras[n] for n in names]
            chs = {n: images[n] for n in names}
            views = ScoreViews(tr.model, cams, [silhouettes[n] for n in names], scale=0.5)
            fitted = []
            for p in poses:
                res, _ = fit_frame(tr.model, cams, chs, p, sliding=tr.sliding, solver=tr.solver, options=tr.options)
                fitted.append((float(views.score(np.asarray(res.params))), np.asarray(res.params)))
            best = max(range(len(fitted)), key=lambda i: (fitted[i][0], -i))
            if current is not None and best == 0:
                return  # the track is as good: it came back by itself
            if poses[best] is own and own is not start:
                mirror = None  # the mirror was brought forward with the other pose: the guard mirrors this one
            start, start_frame = fitted[best][1], int(frame_id)
        tr.params, tr.previous, tr._frames = start, None, (None, start_frame)
        tr.monitor.reset()
        self.rejoined += 1
        tr.open_front_back(mirror)

    def _hold(self, frame_id: int, images: dict) -> None:
        """Keep a set that arrived while a search runs (its chamfer images), at most
        ``catch_up_sets``: when full, every other one is dropped (the newest kept), so the held
        sets span the whole search at a coarser spacing."""
        if self.catch_up_sets <= 0:
            return
        with self._lock:
            self._held.append((int(frame_id), images))
            if len(self._held) > self.catch_up_sets:
                self._held = self._held[::-1][::2][::-1]

    def _catch_up(self) -> None:
        """Bring a found pose forward: fit it (full effort) to each held set after its own in turn.

        Runs after the search, in its time (``search_runner``'s ``then``); the found entry becomes
        ``(frame id of the last set fitted, pose, the search's own pose, mirror)`` (the search's refined mirror
        of the pose brought forward through the same sets) and the held sets are let go."""
        from tracker.fitting.tracking import fit_frame

        tr = self.tracker
        with self._lock:
            found, held, self._held = self._found, self._held, []
        if found is None or found[1] is None:
            return
        frame_id, params, mirror = int(found[0]), np.asarray(found[1], dtype=float), found[3]
        need = self._min_cameras()
        for fid, chs in held:
            names = [n for n in tr.cameras if n in chs]
            if fid <= frame_id or len(names) < need:
                continue
            cams = [tr.cameras[n] for n in names]

            def bring(p):
                res, _ = fit_frame(tr.model, cams, {n: chs[n] for n in names}, p, sliding=tr.sliding,
                                   solver=tr.solver, options=self.base_options)
                return tr.model.clamp(np.asarray(res.params, dtype=float))

            try:
                params, frame_id = bring(params), fid
            except ValueError as exc:  # a set it cannot be fitted to: keep what was brought so far
                log.info("catch-up stopped at frame %d: %s", fid, exc)
                break
            if mirror is not None:
                try:
                    mirror = bring(mirror)
                except ValueError:  # the pose goes on without it (the guard mirrors the pose itself)
                    mirror = None
        with self._lock:
            if self._found is found:
                self._found = (frame_id, params, found[2], mirror)

    def _rejoin_now(self, frame_id: int, timestamp_ns: int, images: dict, silhouettes: dict) -> dict | None:
        """The cheap recovery (``tracker.search.recovery.rejoin`` from the last good pose and the
        tracker's fit) on this set, in the caller's time; when it finds a pose that passes the
        tracker's gate, the set is fitted again from it and that record returned, else None."""
        from tracker.search.recovery import rejoin

        tr = self.tracker
        names = self._search_cameras(images, silhouettes)
        if not names:
            return None
        try:
            res = rejoin(tr.model, [tr.cameras[n] for n in names], {n: silhouettes[n] for n in names},
                         {n: images[n] for n in names}, [tr.last_good, tr.params], options=tr.options.recover_search,
                         n_headings=self.rejoin_headings, accept_iou=self._rejoin_accept_iou(),
                         min_inside_fraction=tr.options.min_inside_fraction)
        except ValueError as exc:
            log.info("rejoin failed: %s", exc)
            return None
        self.search_kinds["rejoin now"] = self.search_kinds.get("rejoin now", 0) + 1
        if res is None:
            return None
        tr.params, tr.previous, tr._frames = tr.model.clamp(np.asarray(res.params, dtype=float)), None, (None, None)
        tr.monitor.reset()
        self.rejoined += 1
        tr.open_front_back(res.clamped_mirror(tr.model))
        return tr.step(frame_id, timestamp_ns, images, silhouettes=silhouettes)

    def _prediction_record(self, frame_id: int, timestamp_ns: int, n_cameras: int) -> dict:
        """The record of a set that arrives while a search runs: not ok, the prediction if any."""
        from tracker.body.kinematics import forward, joint_centre_array

        tr = self.tracker
        what = "initialisation" if tr.last_good is None else "recovery"
        record = {"frame": int(frame_id), "timestamp_ns": int(timestamp_ns), "model": tr.model.name, "ok": False,
                  "cameras": n_cameras, "reason": f"searching: {what} running beside the stream"}
        pred = tr.predict(frame_id)
        if pred is not None:
            joints = joint_centre_array(tr.model, forward(tr.model, pred))
            record.update(params=[float(v) for v in pred],
                          joints={n: [float(v) for v in joints[i]] for i, n in enumerate(tr.model.joint_names)})
        return record

    def __call__(self, frame_id: int, timestamp_ns: int, chamfer: dict) -> dict:
        """The pose record of one frame set (``chamfer``: camera name -> ChamferMessage)."""
        t0 = self.clock()
        self._clipped = any(msg.attrs.get("roi_clipped", 0.0) > 0 for msg in chamfer.values())
        tr = self.tracker
        body = None if self.auto_subject is None or self.searching else self.auto_subject.take_body()
        if body is not None:  # a frame boundary, no search holding the old body
            tr.resize(body)
            self.subject_name = self.auto_subject.name
        if tr.params is None and self.searching:  # initialising: nothing to fit from yet
            record = self._prediction_record(frame_id, timestamp_ns, len(chamfer))
            if self.catch_up_sets > 0:
                self._hold(frame_id, {name: message_to_chamfer(msg) for name, msg in chamfer.items()})
        else:
            images = {name: message_to_chamfer(msg) for name, msg in chamfer.items()}
            silhouettes = {name: silhouette_mask(ci) for name, ci in images.items()}
            if not self.searching:
                self._take_found(frame_id, images, silhouettes)
            if tr.params is None:
                started = self._start_search(frame_id, None, images, silhouettes)
                record = self._prediction_record(frame_id, timestamp_ns, len(chamfer))
                if not started:
                    record["reason"] = "initialisation waits for a set with most cameras' silhouettes"
            else:  # tracking goes on beside a recovery search: it may come back by itself
                level = EFFORT_LEVELS[self.effort.level]
                tr.options = replace(self.base_options, n_samples=level.n_samples,
                                     max_iterations=level.max_iterations, reverse_samples=level.reverse_samples)
                record = tr.step(frame_id, timestamp_ns, images, silhouettes=silhouettes)
                record["effort"] = level.as_record()
                if self.searching:
                    self._hold(frame_id, images)
                else:
                    self.effort.update(self.clock() - t0, fit_ok(record))
                    if self.auto_subject is not None:
                        self.auto_subject.observe(frame_id, record, silhouettes)
                # the fit's verdict, not the unexplained-boundary check's (it only reports: fit_ok)
                if not fit_ok(record):
                    poor = bool(set(record.get("failed") or ()) - {"front_back"})  # a gate limit, not the guard
                    if self.searching:
                        record["reason"] = f"{record.get('reason', 'poor fit')}; searching: recovery running"
                    else:
                        due = poor and self.rejoin_spacing >= 0 and self._sets_since_rejoin >= self.rejoin_spacing
                        if due:
                            self._sets_since_rejoin = 0
                        if due and not self.rejoin_beside:
                            t_rejoin = self.clock()
                            record = self._rejoin_now(frame_id, timestamp_ns, images, silhouettes) or record
                            record["effort"] = level.as_record()
                            record["rejoin_ms"] = 1e3 * (self.clock() - t_rejoin)
                        seeds = [tr.last_good, tr.params]
                        if not fit_ok(record) and tr.monitor.bad_frames >= tr.monitor.patience:
                            self._start_search(frame_id, seeds, images, silhouettes)  # rejoin, then the full search
                        elif due and self.rejoin_beside:
                            self._start_search(frame_id, seeds, images, silhouettes, full=False)
            self._last_frame = int(frame_id)
            self._sets_since_rejoin += 1
        self._last_ok = fit_ok(record)
        if self.subject_name is not None:
            record["subject"] = self.subject_name
        record["fit_ms"] = 1e3 * (self.clock() - t0)
        return record

    def rois(self, frame_id: int) -> dict[str, tuple[int, int, int, int]] | None:
        """Camera name -> ``(x0, y0, x1, y1)`` to segment for ``frame_id``, or None (whole frames:
        see the module docstring)."""
        from tracker.imaging.roi import pose_rois

        tr = self.tracker
        if self.searching or tr.params is None or not self._last_ok or self._clipped or self._last_frame is None:
            return None
        pred = tr.predict(frame_id)
        gap = max(1, int(frame_id) - self._last_frame)
        margin = min(self.roi_max_margin_m, self.roi_margin_m + self.roi_margin_per_frame_m * (gap - 1))
        cams = list(tr.cameras.values())
        # the last fitted pose and the prediction: the body moves between them, the rectangle covers the path
        rects = pose_rois(tr.model, np.stack([pred, tr.params]), cams, margin_m=margin, margin_px=self.roi_margin_px)
        return {cam.name: rect for cam, rect in zip(cams, rects) if rect is not None}
