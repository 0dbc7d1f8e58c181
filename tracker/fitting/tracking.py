"""The tracking loop: one pose record per frame set (DESIGN.md pose record).

Per frame: keep the cameras that sent chamfer images, predict (constant velocity, or the last
pose), fit with Levenberg–Marquardt on the chamfer cost (``tracker.fitting.cost``) from the prediction with
a small prior towards the last fitted pose, measure quality (RMS residual against a limit relative
to the recent frames' median, fraction of predicted contour points inside the silhouettes, and
now and then or when those look suspect the silhouette IoU; ``TrackerOptions``) and emit the
record.  A frame whose quality is below the thresholds is reported
``ok: false`` ("poor fit"); after ``patience`` such frames in a row (``tracker.search.recovery.LossMonitor``)
the pose is searched again from the silhouettes, seeded by the last good pose
(``tracker.search.recovery.recover``).  Without ``initial_params`` the first frame is
initialised from the silhouettes.

Never raises on data: a frame that cannot be solved (no camera, all silhouettes empty, no
initial pose, quality below the thresholds) gives ``ok: false`` and a ``reason``.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, replace
from typing import Callable, Mapping, Sequence

import cv2
import numpy as np

from capture.camera import Camera
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import ROOT_TRANSLATION, BodyModel
from tracker.fitting.cost import ChamferCost
from tracker.fitting.hypotheses import AMBIGUOUS, FrontBackGuard, FrontBackOptions
from tracker.fitting.sampler import ChamferViews, in_camera_order
from tracker.fitting.uncovered import FAILED as UNCOVERED, UncoveredWatch
from tracker.fitting.solver import SolverResult, least_squares_fd, levenberg_marquardt, robust_cost
from tracker.search.initialise import SearchOptions, initialise
from tracker.search.limbs import (ARM_STARTS, ARMS, EXCHANGED, LEGS, UNSURE, StrideWatch, ankle_crossing,
                                  ankle_separation, arm_candidates, chain_joint_distance, exchange_verdict,
                                  leg_candidates, limb_dofs, side_chains)
from tracker.search.appearance import view_colours
from tracker.search.mirror import hypothesis_cost, mirror_params
from tracker.search.recovery import LossMonitor, recover
from tracker.search.scoring import ScoreViews

__all__ = ["Tracker", "TrackerOptions", "Verdict", "fit_frame", "prior_weights", "palm_model", "refit_options",
           "MAX_EXTRAPOLATION"]

MAX_EXTRAPOLATION = 3.0
"""The constant-velocity prediction extrapolates at most this many times the last step."""

_SAME_CHAIN_RAD = 0.05  # a limb whose angles two fits agree on within this (rad) is not exchanged between them


@dataclass(frozen=True)
class TrackerOptions:
    """Fitting options of the ``Tracker`` (defaults tuned on the synthetic hop session, bench/tracker.py).

    Each field's meaning and unit is commented where it is declared; the measured effect of the
    settings and their tuning history are in docs/tuning.md, "Tracker".

    Parameters
    ----------
    n_samples, visibility, max_iterations, ftol, xtol, rtol, damping, diagonal_floor
        The fit: ``ChamferCost`` sampling and occlusion, ``levenberg_marquardt`` stopping and damping.
    loss, f_scale, truncate_px, prior_m, prior_rad
        Robust loss and its scale, distance truncation, priors towards the last fitted pose.
    reverse_weight, reverse_samples, reverse_min_px, reverse_cover_px
        The silhouette -> model term of ``tracker.fitting.cost`` (weight 0: off).
    palm_length
        The hands' length of the body the tracker fits (``palm_model``; None: the model's).
    constant_velocity, velocity_damping, restart_step, restart_exchange
        Start from the constant-velocity extrapolation (that fraction of its step), the last pose, and limbs of both.
    max_rms_px, rms_ratio, rms_window, max_rms_ceiling_px, min_inside_fraction, min_iou
        Quality limits of a good frame (a worse frame is reported ``ok: false``).
    iou_every, iou_check_coverage, iou_rms_jump
        When the silhouette IoU check (costly: a render) runs.
    lost_iou_margin, lost_iou_floor, iou_window, soft_search_gap
        Which IoU failures count towards a lost track (the rest are only not ok), and how often.
    front_back_every, front_back_iterations, front_back_margin
        The periodic front/back check.
    limb_every, limb_flag_coverage, limb_coverage_drop, limb_dead_band, limb_iterations, limb_margin, limb_same,
    limb_crossed, limb_colour_margin, limb_colour_match, limb_colour_share, limb_colour_views, limb_colour_due : limbs
    initialise_search, recover_search : SearchOptions
        The searches from the silhouettes: the first frame; after ``patience`` bad frames.
    """

    #: contour points per side of a part
    n_samples: int = 8
    #: when occlusion is recomputed (``ChamferCost``: "step", "frame", "always", "none")
    visibility: str = "step"
    #: LM trial steps per frame
    max_iterations: int = 12
    #: LM stops at this relative cost change
    ftol: float = 3e-2
    #: ... or this relative step size
    xtol: float = 1e-4
    #: ... or when the largest linearised residual change is below this, px
    rtol: float = 1.0
    #: robust loss on the pixel residuals (``tracker.fitting.solver``)
    loss: str = "huber"
    #: its scale, px
    f_scale: float = 3.0
    #: distances above it are clipped (zero gradient), px
    truncate_px: float = 30.0
    #: prior weight on the root translation towards the last fitted pose (not the extrapolation), px² per m²
    prior_m: float = 200.0
    #: prior weight on the rotations towards the last fitted pose, px² per rad²
    prior_rad: float = 30.0
    #: length of the hands' cones of the body the ``Tracker`` fits, searches and gates with, fraction
    #: of height (None: the model's own); e.g. 0.06, the palm: the part of a hand that is in the
    #: silhouette whatever the fingers do
    palm_length: float | None = None
    #: weight of the silhouette -> model term (0: off)
    reverse_weight: float = 1.0
    #: observed boundary samples per camera of that term
    reverse_samples: int = 150
    #: a sample nearer than this to the model's contour has no residual, px
    reverse_min_px: float = 2.0
    #: a sample on the model's silhouette grown by this has no residual, px (None: test off; it is
    #: what makes knossow54 and 4-camera tracking converge, at a cost per frame)
    reverse_cover_px: float | None = 1.0
    #: LM initial damping
    damping: float = 1e-3
    #: floor of the damping diagonal
    diagonal_floor: float = 0.0
    #: start from ``2 p_t - p_{t-1}`` (fewer iterations, lower joint error on the hop)
    constant_velocity: bool = True
    #: fraction of the constant-velocity step the prediction takes (1: all of it; the live fitter's is
    #: ``service.workers.live_fit.LIVE_VELOCITY_DAMPING``)
    velocity_damping: float = 1.0
    #: a second start: when the prediction moves some joint centre more than ``restart_step`` × the
    #: body's height from the last fitted pose, or the fit from it is suspect (``Tracker._suspect``), the
    #: frame is fitted from the last fitted pose too and the fit of lower ``SolverResult.cost`` is kept
    #: (None: off; the live fitter's is ``service.workers.live_fit.LIVE_RESTART_STEP``)
    restart_step: float | None = None
    #: with a second start, also try the kept fit with one limb (a side's arm or leg) from the other fit: the
    #: one of lowest data cost, when lower than the kept fit's, is fitted and kept if its fit costs less (the
    #: two starts often get different limbs right: after a frame gap, the prediction an arm in a fast swing,
    #: the last pose the rest)
    restart_exchange: bool = True
    #: the RMS limit of a good frame is ``min(max_rms_ceiling_px, max(max_rms_px, rms_ratio × median
    #: RMS of the last rms_window good frames))``: the RMS level is set by the segmentation (shadows,
    #: missing edges), not by the pose, px
    max_rms_px: float = 6.0
    rms_ratio: float = 2.5
    rms_window: int = 30
    max_rms_ceiling_px: float = 15.0
    #: a frame with fewer contour points on the silhouettes is bad (a drifted model sticks out)
    min_inside_fraction: float = 0.6
    #: a frame whose silhouette IoU (``ScoreViews`` at half resolution) is lower is bad: it catches a
    #: pose that fits the contours locally yet misses or overshoots whole limbs
    min_iou: float = 0.8
    #: the IoU is checked (when the frame brings silhouettes) every ``iou_every`` frames, after a bad
    #: frame, and when a cheap figure is near its limit: coverage below ``iou_check_coverage``, RMS
    #: above ¾ of its limit, or an inside fraction within 0.1 of its limit (1: every frame)
    iou_every: int = 10
    iou_check_coverage: float = 0.8
    #: ... and when the RMS exceeds ``iou_rms_jump`` × the median RMS of the recent good frames (a
    #: fit that jumps off the body without reaching the RMS limit; None: off)
    iou_rms_jump: float | None = 1.5
    #: a body that is not the model's shape cannot reach ``min_iou``: a frame that fails only the IoU
    #: limit yet reaches ``max(lost_iou_floor, min(min_iou, reference - lost_iou_margin))`` (reference:
    #: the median IoU of the last ``iou_window`` frames that passed the other limits; none yet: the
    #: floor) is reported not ok but does not count towards a lost track (no search; no velocity
    #: out of it either) (``lost_iou_margin`` None, the default: every not-ok frame counts; 0.04 is
    #: what bench/robustness.py measures)
    lost_iou_margin: float | None = None
    lost_iou_floor: float = 0.65
    iou_window: int = 30
    #: ... except that such frames do count once ``soft_search_gap`` frames have passed since the last
    #: search: a track that stays below ``min_iou`` is searched again now and then (a drifting limb
    #: keeps the IoU near the body's usual), not on every frame
    soft_search_gap: int = 30
    #: a body unlike the model overshoots the silhouettes where the pose is right, a lost limb leaves the
    #: silhouette's own limb uncovered: a frame that fails only ``min_iou`` (at or above
    #: ``iou_explained_floor``) is excused (``Verdict.excused``: reported ok, tracked as before) when the
    #: share of the silhouettes the model leaves uncovered is at most ``iou_unexplained_margin`` above the
    #: median share of the last ``iou_window`` frames that passed ``min_iou`` (at least
    #: ``iou_explained_samples`` of them), unless the front/back guard was ambiguous within the last
    #: ``iou_excuse_after_ambiguous`` frames (the side of the pose just settled, the excuse vouches only
    #: for the body) (``iou_unexplained_margin`` None: off)
    iou_unexplained_margin: float | None = 0.015
    iou_explained_floor: float = 0.75
    iou_explained_samples: int = 2
    iou_excuse_after_ambiguous: int = 30
    #: silhouettes hardly tell a body from its mirror, so a track can run turned round: every
    #: ``front_back_every`` frames that bring silhouettes (0: never; not right after a search) the
    #: mirror of the fit is fitted too (``front_back_iterations`` LM steps); when its
    #: ``hypothesis_cost`` is ``front_back_margin`` lower it is taken and fitted to convergence
    front_back_every: int = 60
    front_back_iterations: int = 12
    front_back_margin: float = 0.5
    #: lost or exchanged limbs (``tracker.search.limbs``): when the fit leaves more of the observed
    #: silhouette boundary unexplained than usual (coverage below the median of the last ``rms_window``
    #: good frames' minus ``limb_coverage_drop``, at most every ``limb_every`` frames) or when the legs
    #: have crossed (ankles apart along the heading by more than ``limb_dead_band`` × height, on the other
    #: side from the last time), the legs exchanged, each leg straight, each arm hanging, bent, raised and
    #: in the last good pose are fitted (``limb_iterations`` LM steps; ``limbs.leg_candidates``,
    #: ``limbs.arm_candidates``); the legs', the left arm's and the right arm's best are judged apart: one
    #: whose ``hypothesis_cost`` is ``limb_margin`` lower is taken, one lower by less whose knees/ankles or
    #: elbows/wrists end more than ``limb_same`` × height away makes the frame not ok ("limbs"), and with
    #: ``limb_flag_coverage`` so does a coverage still below the limit after the check (off: the model's own
    #: hop has frames with a good fit below it, docs/robustness.md round 7) (0 ``limb_every``: off)
    limb_every: int = 5
    limb_flag_coverage: bool = False
    limb_coverage_drop: float = 0.03
    limb_dead_band: float = 0.08
    limb_iterations: int = 6
    limb_margin: float = 0.5
    limb_same: float = 0.04
    #: crossed legs (``tracker.search.limbs.ankle_crossing``: the left ankle more than ``limb_crossed`` ×
    #: height on the right ankle's side) make the limb check due, lost or not, at most every
    #: ``limb_every`` frames, with the ``"uncrossed"`` start among its legs' (None: off)
    limb_crossed: float | None = 0.03
    #: a limb lost inside the silhouette (its fit as good as a right one's): with the frame's colour
    #: images and the front/back guard's learned colours, each forearm and hand is sampled per camera
    #: (``tracker.search.appearance.view_colours``); in a camera it looks lost when its samples are
    #: ``limb_colour_margin`` nearer the learned colour of a part of the trunk, upper arms or legs than
    #: its own and within ``limb_colour_match`` of it (``AppearanceModel.part_distances``: squared
    #: distances in units of the model's ``sigma``); lost in more than ``limb_colour_share`` of the cameras that see it, at
    #: least ``limb_colour_views`` of them, it makes an otherwise good frame not ok ("limb_colour")
    #: (None: off; the constants' source: docs/robustness.md, round 10)
    limb_colour_margin: float | None = 2.5
    limb_colour_match: float = 1.0
    limb_colour_share: float = 0.5
    limb_colour_views: int = 1
    #: a frame whose colour check found a limb lost makes the next frame's limb check due (at most every
    #: ``limb_every`` frames, not on a frame that counts towards a lost track)
    limb_colour_due: bool = True
    #: a limb lost against the body leaves its own outline unexplained in the cameras that see it beside
    #: the body, while the global figures stay good: every frame's share of each camera's observed boundary
    #: samples farther than ``uncovered_tol`` × the body's height in that camera's pixels (at the root's
    #: depth) from the model (1 - ``CostTerms.coverage_per_camera``) is compared with that camera's median
    #: over the last ``iou_window`` frames reported ok (``tracker.fitting.uncovered``, at least
    #: ``uncovered_samples`` of them); above it by more than ``uncovered_margin`` in some camera on
    #: ``uncovered_frames`` frames in a row, it makes an otherwise good frame not ok ("uncovered"; the track
    #: goes on as before) (None: off)
    uncovered_margin: float | None = 0.05
    uncovered_tol: float = 0.045
    uncovered_samples: int = 5
    uncovered_frames: int = 2
    #: a lost track's search also runs the first frame's search from the silhouettes alone and keeps, of the two
    #: fits, the one of lower ``hypothesis_cost`` (the recovery seeded by the last good pose stays near it)
    recover_full: bool = False
    #: the first frame's search (``tracker.search.initialise.initialise``)
    initialise_search: SearchOptions = SearchOptions()
    #: the search after ``patience`` bad frames (``tracker.search.recovery.recover``); three refined
    #: candidates, as the initialisation
    recover_search: SearchOptions = SearchOptions.for_recovery(keep=3)


def prior_weights(model: BodyModel, options: TrackerOptions) -> np.ndarray:
    """Per-parameter prior weights: ``prior_m`` on the root translation, ``prior_rad`` on rotations.

    Parameters
    ----------
    model : BodyModel
    options : TrackerOptions

    Returns
    -------
    ndarray, shape (n_params,)
        px² per m² or per rad².
    """
    return np.where(model.param_kind == ROOT_TRANSLATION, options.prior_m, options.prior_rad)


def refit_options(options: TrackerOptions) -> TrackerOptions:
    """``options`` for fitting frames again (``Tracker.twin``, ``SceneTracker.retrack``): the silhouette IoU
    checked on every frame, so that a refit that replaces a frame's first fit is judged by every limit."""
    return replace(options, iou_every=1)


def palm_model(model: BodyModel, length: float | None) -> BodyModel:
    """``model`` with every ``*_hand`` part's cone cut to ``length`` × height (metres along the
    hand from the wrist; a shorter hand is kept as it is); None: ``model`` itself.  The kinematics,
    parameters and joint centres are the model's."""
    if length is None:
        return model
    if not (np.isfinite(length) and length > 0):
        raise ValueError(f"palm_length: expected a positive fraction of height, got {length}")
    cones = np.array(model.cones)
    hands = [i for i, n in enumerate(model.part_names) if n.endswith("_hand")]
    cones[hands, 4] = np.minimum(cones[hands, 4], np.maximum(cones[hands, 3] + 1e-6, length * model.height_m))
    cones.setflags(write=False)
    return replace(model, cones=cones)


def _chamfer_cost(model: BodyModel, cameras: Sequence, chamfer: Mapping[str, object], options: TrackerOptions, *,
                 sliding: bool = True, visibility: str | None = None) -> ChamferCost:
    """The ``ChamferCost`` a frame is fitted with under ``options`` (``visibility``: the options' unless
    given; ``fit_frame``'s cost)."""
    return ChamferCost(model, cameras, in_camera_order(chamfer, cameras), sliding=sliding, n_samples=options.n_samples,
                       visibility=options.visibility if visibility is None else visibility,
                       truncate_px=options.truncate_px, reverse_weight=options.reverse_weight,
                       reverse_samples=options.reverse_samples, reverse_min_px=options.reverse_min_px,
                       reverse_cover_px=options.reverse_cover_px)


def fit_frame(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, start: np.ndarray, *,
              prediction: np.ndarray | None = None, sliding: bool = True, solver: str = "lm",
              options: TrackerOptions = TrackerOptions(), penalty=None) -> tuple[SolverResult, ChamferCost]:
    """Fit one frame from ``start`` with the prior term towards ``prediction``.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    chamfer : mapping str -> ChamferSampler
        Camera name -> sampler (``tracker.fitting.sampler``), at least every camera of ``cameras``.
    start : ndarray, shape (n_params,)
    prediction : ndarray, shape (n_params,), optional
        Centre of the prior (default ``start``).
    sliding : bool
        Use the sliding term of the contour Jacobian.
    solver : {"lm", "lsq"}
        Analytic LM, or scipy with finite differences.
    options : TrackerOptions
    penalty : object with ``residuals(model, params, jacobian=, pose=)`` -> (r, J or None), optional
        Extra residuals stacked under the cost's (``tracker.fitting.props.PropPenalty``).

    Returns
    -------
    result : SolverResult
    cost : ChamferCost
    """
    cost = _chamfer_cost(model, cameras, chamfer, options, sliding=sliding)
    prior = start if prediction is None else prediction
    kw = dict(lower=model.lower, upper=model.upper, prior=model.clamp(prior),
              prior_weight=prior_weights(model, options), loss=options.loss, f_scale=options.f_scale,
              max_iterations=options.max_iterations, ftol=options.ftol, xtol=options.xtol)
    lm_only = dict(damping=options.damping, diagonal_floor=options.diagonal_floor, rtol=options.rtol)
    if solver == "lm":
        res = levenberg_marquardt(_with_penalty(cost, model, penalty, compact=True, structured=True), start,
                                  **lm_only, **kw)
    elif solver == "lsq":
        res = least_squares_fd(_with_penalty(cost, model, penalty, compact=False), start, **kw)
    else:
        raise ValueError(f"solver: expected 'lm' or 'lsq', got {solver!r}")
    return res, cost


def _with_penalty(cost: ChamferCost, model: BodyModel, penalty, *, compact: bool, structured: bool = False):
    """``cost.residual_fn(compact=..., structured=...)`` with ``penalty``'s residuals stacked under (None:
    as is)."""
    if penalty is None:
        return cost.residual_fn(compact=compact, structured=structured)

    def fun(x, jacobian):
        t = cost.evaluate(x, jacobian=jacobian, compact=compact, structured=structured)
        r, J = penalty.residuals(model, x, jacobian=jacobian, pose=t.pose)
        if not jacobian:
            return np.concatenate([t.residuals, r]), None
        return (np.concatenate([t.residuals, r]),
                t.jacobian.with_rows(J) if structured else np.vstack([t.jacobian, J]))

    return fun


def _silhouette_empty(chamfer, silhouette) -> bool:
    if silhouette is not None:
        s = np.asarray(silhouette)
        if s.ndim == 2 and s.dtype == np.uint8 and s.size:
            return cv2.countNonZero(s) == 0
        return not np.any(s)
    q = getattr(chamfer, "silhouette_q", None)
    if q is None:
        return False
    return q.size == 0 or int(q.min()) > 0


@dataclass(frozen=True)
class Verdict:
    """The quality gate's verdict on a fit: false when it passed.

    Attributes
    ----------
    text : str
        Why it failed, for the pose record's ``reason`` ("" when it passed).
    failed : tuple of str
        The limits it failed, from ``"rms"``, ``"inside"``, ``"iou"`` (the pose record's ``failed``).
    excused : bool
        It failed only the IoU, and the silhouettes' uncovered share says the body is unlike the model,
        not the pose wrong (``TrackerOptions.iou_unexplained_margin``): reported ok, tracked as failed.
    """

    text: str = ""
    failed: tuple = ()
    excused: bool = False

    def __bool__(self) -> bool:
        return bool(self.failed)

    def __str__(self) -> str:
        return self.text


class Tracker:
    """Frame-to-frame tracker of one person.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera (the studio; a frame may bring any subset)
    sliding : use the sliding term of the contour Jacobian
    solver : ``"lm"`` (analytic Jacobian) or ``"lsq"`` (scipy, finite differences)
    initial_params : (n_params,) start pose; without it the first frame is initialised by
        ``tracker.search.initialise.initialise`` (the frame must bring ``silhouettes``)
    options : TrackerOptions
    recover : re-initialise once ``patience`` consecutive frames were bad and the frame brings
        ``silhouettes`` (``tracker.search.recovery`` seeded by the last good pose; the T/A-pose search of
        ``tracker.search.initialise`` when there was none)
    clock : callable returning seconds (latency measurement), default ``time.perf_counter``
    front_back : ``tracker.fitting.hypotheses.FrontBackOptions`` of the front/back guard (None: no
        guard): from an automatic initialisation and after every re-initialisation the pose's mirror
        is tracked too and frames are not ok ("front/back ambiguous") until the evidence (fit,
        feet, colour of the frame's ``images``, walking direction) separates them; a pose given
        as ``initial_params`` is taken as resolved; with the guard the periodic check of
        ``TrackerOptions.front_back_every`` is not run (the guard's own checks replace it)

    Attributes
    ----------
    params : (n_params,) the last fitted pose (None before initialisation)
    last_good : (n_params,) the last pose of a good frame
    last_result : SolverResult of the last fit
    n_initialisations, n_front_back_checks, n_turned, n_limb_checks, n_limb_switches, n_restarts, n_restarts_taken :
        searches, front/back checks, mirrors and limbs taken, fits from the last pose too and those kept
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], *, sliding: bool = True, solver: str = "lm",
                 initial_params=None, options: TrackerOptions = TrackerOptions(), recover: bool = True,
                 patience: int = 3, clock: Callable[[], float] = time.perf_counter,
                 front_back: FrontBackOptions | None = FrontBackOptions()) -> None:
        if solver not in ("lm", "lsq"):
            raise ValueError(f"solver: expected 'lm' or 'lsq', got {solver!r}")
        self.model = palm_model(model, options.palm_length)
        self.cameras = {c.name: c for c in cameras}
        if len(self.cameras) != len(cameras):
            raise ValueError("cameras: names must be unique")
        self.sliding = bool(sliding)
        self.solver = solver
        self._uncovered_settings = False  # none yet: setting the options builds the watch
        self.options = options
        self.recover = bool(recover)
        #: extra residuals of every frame's fit (``fit_frame``'s ``penalty``; None: none)
        self.penalty = None
        self.clock = clock
        # the frame's own RMS limit (``rms_limit``) is applied by ``_bad``; the monitor counts bad frames
        self.monitor = LossMonitor(max_rms_px=max(options.max_rms_px, options.max_rms_ceiling_px),
                                   min_inside_fraction=options.min_inside_fraction, patience=patience)
        self._good_rms: list[float] = []
        self._good_iou: list[float] = []  # IoUs of frames that passed the RMS and inside limits
        self._good_unexplained: list[float] = []  # uncovered silhouette shares of frames that passed min_iou
        self._since_ambiguous = 1 << 30  # frames since the front/back guard's last ambiguous frame
        self._since_search = 0  # frames since the last search (initialisation or recovery)
        self._since_iou = options.iou_every  # the first frame is checked
        self._since_front_back = 0
        self.n_front_back_checks = 0
        self._good_cov: list[float] = []  # coverage of the frames that passed the gate's limits
        self._since_limbs = options.limb_every
        self._colour_lost = False  # the last frame's colour check found a distal limb lost
        self.stride = StrideWatch(options.limb_dead_band * model.height_m if options.limb_dead_band > 0 else 1.0)
        self.n_limb_checks = 0
        self.n_limb_switches = 0
        self.n_turned = 0
        self.n_restarts = self.n_restarts_taken = self.n_restart_exchanges = 0
        self._last_bad = False
        self.params: np.ndarray | None = None
        self.previous: np.ndarray | None = None
        self._frames: tuple[int | None, int | None] = (None, None)  # frame ids of ``previous`` and ``params``
        self.last_good: np.ndarray | None = None
        if initial_params is not None:
            p = np.asarray(initial_params, dtype=float)
            if p.shape != (model.n_params,) or not np.all(np.isfinite(p)):
                raise ValueError(f"initial_params: expected a finite array of shape ({model.n_params},)")
            self.params = model.clamp(p)
        self.last_result: SolverResult | None = None
        self.n_initialisations = 0
        self.guard = None if front_back is None else FrontBackGuard(self.model, front_back)
        if self.guard is not None and self.params is not None:
            self.guard.state = "resolved"

    @property
    def options(self) -> TrackerOptions:
        """The tracker's options; setting them rebuilds the unexplained-boundary watch (``uncovered``)
        when its settings change (``uncovered_margin`` None: no watch) and keeps it, with its history,
        when they do not."""
        return self._options

    @options.setter
    def options(self, options: TrackerOptions) -> None:
        self._options = options
        watch = (None if options.uncovered_margin is None else
                 (options.uncovered_margin, options.iou_window, options.uncovered_samples, options.uncovered_frames))
        if watch != self._uncovered_settings:
            self._uncovered_settings = watch
            self.uncovered = None if watch is None else UncoveredWatch(
                margin=watch[0], window=watch[1], min_samples=watch[2], frames=watch[3])

    def resize(self, model: BodyModel) -> None:
        """Track with ``model`` from the next frame on: the same model's parameters, other sizes
        (a calibrated subject); the pose, its velocity and the front/back guard's state are kept."""
        if model.param_names != self.model.param_names:
            raise ValueError(f"resize: model {model.name!r} has other parameters than {self.model.name!r}")
        self.model = palm_model(model, self.options.palm_length)
        if self.guard is not None:
            self.guard.resize(self.model)
        if self.uncovered is not None:
            self.uncovered.reset()  # another body leaves another share uncovered

    def predict(self, frame_id: int | None = None) -> np.ndarray | None:
        """Start pose for frame ``frame_id`` (default: the next frame set), shape (n_params,); None
        before initialisation.

        Constant velocity when enabled: ``p + d (p - p_prev)``, ``d`` = ``TrackerOptions.velocity_damping``,
        the step scaled by the ratio of the frame-id gaps (to ``frame_id`` over between the last two
        fits, at most :data:`MAX_EXTRAPOLATION`) when both are known, so a live tracker that fits every
        n-th frame extrapolates by the frames elapsed.
        """
        if self.params is None:
            return None
        if self.options.constant_velocity and self.previous is not None:
            scale = 1.0
            f_prev, f_last = self._frames
            if frame_id is not None and f_prev is not None and f_last is not None and f_last > f_prev:
                scale = min(MAX_EXTRAPOLATION, max(0.0, (int(frame_id) - f_last) / (f_last - f_prev)))
            scale *= float(self.options.velocity_damping)
            if scale == 1.0:
                return self.model.clamp(2.0 * self.params - self.previous)
            return self.model.clamp(self.params + scale * (self.params - self.previous))
        return self.params

    def _search(self, cams, chamfer, silhouettes, hint) -> tuple[np.ndarray, np.ndarray | None]:
        """Initialisation (hint None) or recovery from silhouettes: the pose and the search's refined mirror
        of it (``InitResult.mirror``, None if none); raises ValueError on failure."""
        self.n_initialisations += 1
        self._since_search = 0
        sils = {c.name: silhouettes[c.name] for c in cams}
        chs = {c.name: chamfer[c.name] for c in cams}
        if hint is None:
            res = initialise(self.model, cams, sils, chs, options=self.options.initialise_search)
        else:
            res = recover(self.model, cams, sils, chs, hint, options=self.options.recover_search)
        return self.model.clamp(np.asarray(res.params, dtype=float)), res.clamped_mirror(self.model)

    def _full_search(self, cams, chamfer, silhouettes, chs, views, fitted, mirror):
        """``(fitted, mirror)`` of the recovery, or of the initialisation's search from the silhouettes alone
        fitted the same way when its ``hypothesis_cost`` is lower (``TrackerOptions.recover_full``)."""
        try:
            found, mirror3 = self._search(cams, chamfer, silhouettes, None)
            other = self._fit(cams, chs, found)
        except ValueError:
            return fitted, mirror
        v = views()

        def cost(f):
            q = np.asarray(f[0].params)
            return hypothesis_cost(self.model, q, f[2], float(v.score(q)))

        return (other, mirror3) if cost(other) < cost(fitted) else (fitted, mirror)

    def open_front_back(self, mirror: np.ndarray | None) -> None:
        """A search's pose was taken: the front/back guard's question is opened at it (no guard: nothing),
        the search's refined ``mirror`` (n_params,) or None offered as the mirror's first start."""
        if self.guard is not None:
            self.guard.reset()
            self.guard.offer_mirror(mirror)

    def twin(self) -> "Tracker":
        """A copy of this tracker that fits frames again from its state (``service.offline``'s refits of a
        warm-up or of a refused stretch, latest first); this tracker is left as it is.

        The copy has no velocity into its first frame and checks the silhouette IoU on every frame
        (``TrackerOptions.iou_every`` 1): a refit replaces a frame's first fit when the gate passes it, so
        it is judged by every limit the first fit was."""
        twin = copy.deepcopy(self)
        twin.previous = None
        twin.options = refit_options(twin.options)
        return twin

    def _fit(self, cams, chs, start):
        prior = start if self.params is None else self.params
        res, cost = fit_frame(self.model, cams, chs, start, prediction=prior, sliding=self.sliding,
                              solver=self.solver, options=self.options, penalty=self.penalty)
        terms = cost.evaluate(np.asarray(res.params))
        return res, terms, terms.rms_px(), terms.inside_fraction()

    def _restart_due(self, start: np.ndarray, terms) -> bool:
        """Whether the frame is fitted from the last fitted pose too (``TrackerOptions.restart_step``):
        ``start`` (the prediction) moves a joint centre more than ``restart_step`` × height from
        ``params``, or the fit from it (``terms``) is suspect."""
        step = self.options.restart_step
        if step is None or self.params is None or start is self.params or np.array_equal(start, self.params):
            return False
        if self._suspect(terms):
            return True
        moved = (joint_centre_array(self.model, forward(self.model, np.asarray(start)))
                 - joint_centre_array(self.model, forward(self.model, self.params)))
        return bool(np.max(np.einsum("ij,ij->i", moved, moved)) > (step * self.model.height_m) ** 2)

    def _restart(self, cams, chs, res, terms, rms, inside):
        """The second start: the frame fitted from the last fitted pose too; ``(res, terms, rms, inside)`` of
        the cheaper of the two fits (``res`` is the fit from the prediction), or of the fit with a limb of
        the other (``_exchange_limb``)."""
        self.n_restarts += 1
        res2, terms2, rms2, inside2 = self._fit(cams, chs, self.params)
        first, second = (res, terms, rms, inside), (res2, terms2, rms2, inside2)
        kept, other = (second, first) if res2.cost < res.cost else (first, second)
        if self.options.restart_exchange:
            kept = self._exchange_limb(cams, chs, kept, other[0])
        self.n_restarts_taken += int(kept[0] is not res)
        return kept

    def _exchange_limb(self, cams, chs, kept, other):
        """``kept`` ``(res, terms, rms, inside)``, or the fit from ``kept``'s pose with one side's arm or leg
        taken from ``other`` (a ``SolverResult``) when that start's data cost is the lowest of the
        exchanges and below ``kept``'s, and its fit's ``SolverResult.cost`` is below ``kept``'s
        (``TrackerOptions.restart_exchange``)."""
        o, model = self.options, self.model
        p, q = np.asarray(kept[0].params), np.asarray(other.params)
        starts = []
        for _, dofs in side_chains(model):
            if np.max(np.abs(p[dofs] - q[dofs])) > _SAME_CHAIN_RAD:
                x = p.copy()
                x[dofs] = q[dofs]
                starts.append(x)
        if not starts:
            return kept
        cost = _chamfer_cost(model, cams, chs, o, sliding=self.sliding, visibility="frame")

        def data_cost(x):
            return robust_cost(cost.evaluate(x, compact=True).residuals, loss=o.loss, f_scale=o.f_scale)

        c0 = data_cost(p)  # first: the occlusion of the kept pose is the one every start is scored with
        costs = [data_cost(x) for x in starts]
        best = int(np.argmin(costs))
        if not costs[best] < c0:
            return kept
        self.n_restart_exchanges += 1
        got = self._fit(cams, chs, starts[best])
        return got if got[0].cost < kept[0].cost else kept

    def rms_limit(self) -> float:
        """RMS (pixels) above which the current frame is bad (``TrackerOptions.max_rms_px``)."""
        o = self.options
        lim = o.max_rms_px
        if self._good_rms:
            lim = max(lim, o.rms_ratio * float(np.median(self._good_rms)))
        return min(lim, o.max_rms_ceiling_px)

    def lost_iou_limit(self) -> float:
        """IoU below which a frame counts towards a lost track (``TrackerOptions.lost_iou_margin``)."""
        o = self.options
        if o.lost_iou_margin is None:
            return o.min_iou
        if not self._good_iou:
            return min(o.min_iou, o.lost_iou_floor)
        return min(o.min_iou, max(o.lost_iou_floor, float(np.median(self._good_iou)) - o.lost_iou_margin))

    def _soft(self, bad: Verdict) -> bool:
        """The frame failed only the IoU limit and stays above ``lost_iou_limit``, and the last search
        is recent (``soft_search_gap``): not ok, not lost."""
        return (bad.failed == ("iou",) and self._last_iou is not None and self._last_iou >= self.lost_iou_limit()
                and self._since_search < self.options.soft_search_gap)

    def _suspect(self, terms) -> bool:
        """A cheap figure is near its limit: RMS above ¾ of it, inside fraction within 0.1 of it,
        or coverage below ``iou_check_coverage`` (``TrackerOptions``)."""
        o = self.options
        rms, inside, cov = terms.rms_px(), terms.inside_fraction(), terms.coverage()
        return (not rms <= 0.75 * self.rms_limit() or not inside >= o.min_inside_fraction + 0.1
                or (np.isfinite(cov) and cov < o.iou_check_coverage))

    def _iou_due(self, terms) -> bool:
        """Whether the (costly) silhouette IoU check runs on this frame (``TrackerOptions``)."""
        o = self.options
        jump = (o.iou_rms_jump is not None and bool(self._good_rms)
                and not terms.rms_px() <= o.iou_rms_jump * float(np.median(self._good_rms)))
        return self._last_bad or self._since_iou + 1 >= o.iou_every or self._suspect(terms) or jump

    def _iou_explained(self, iou: float, unexplained: float) -> bool:
        """Whether a frame below ``min_iou`` leaves no more of the silhouettes uncovered than the
        track's recent good frames (``TrackerOptions.iou_unexplained_margin``)."""
        o = self.options
        return (o.iou_unexplained_margin is not None and iou >= o.iou_explained_floor
                and len(self._good_unexplained) >= max(1, o.iou_explained_samples)
                and unexplained <= float(np.median(self._good_unexplained)) + o.iou_unexplained_margin)

    def _bad(self, terms, views) -> "Verdict":
        """Why the fit at ``terms`` is poor (false when it is good); ``views``: a callable returning
        ScoreViews (built on first use), or None (no IoU check)."""
        o = self.options
        rms, inside = terms.rms_px(), terms.inside_fraction()
        lim = self.rms_limit()
        why, failed, explained = [], [], False
        if not (np.isfinite(rms) and rms <= lim):
            why.append(f"rms {rms:.2f} px > {lim:.3g}")
            failed.append("rms")
        if not (np.isfinite(inside) and inside >= o.min_inside_fraction):
            why.append(f"{100 * inside:.0f}% of contour on the silhouettes < {100 * o.min_inside_fraction:.0f}%")
            failed.append("inside")
        if views is not None and (why or self._iou_due(terms)):
            ious, uncovered = views().ious_unexplained(np.asarray(terms.pose.params))
            iou, unexplained = float(ious.mean()), float(uncovered.mean())
            self._last_iou = iou
            if not iou >= o.min_iou:
                why.append(f"silhouette IoU {iou:.2f} < {o.min_iou:g}")
                failed.append("iou")
                explained = self._iou_explained(iou, unexplained)
            if not why:
                self._good_unexplained = (self._good_unexplained + [unexplained])[-o.iou_window:]
            if not why or (failed == ["iou"] and iou >= self.lost_iou_limit()):
                self._good_iou = (self._good_iou + [iou])[-o.iou_window:]
        return Verdict("; ".join(why), tuple(failed), explained and failed == ["iou"])

    def _front_back(self, cams, chs, res, terms, views):
        """The front/back check (``TrackerOptions``): ``(res, terms)`` of the turned pose when the
        mirror of the fit ``res`` scores better, else None."""
        o = self.options
        self.n_front_back_checks += 1
        p = np.asarray(res.params)
        mp = self.model.clamp(mirror_params(self.model, p))
        res_m, cost_m = fit_frame(self.model, cams, chs, mp, sliding=self.sliding, solver=self.solver,
                                  options=replace(o, max_iterations=o.front_back_iterations), penalty=self.penalty)
        pm = np.asarray(res_m.params)
        v = views()
        iou = self._last_iou if self._last_iou is not None else float(v.score(p))
        kept = hypothesis_cost(self.model, p, terms.rms_px(), iou)
        turned = hypothesis_cost(self.model, pm, cost_m.evaluate(pm).rms_px(), float(v.score(pm)))
        if not turned < kept - o.front_back_margin:
            return None
        # turned: converge fully from there (the mirror of a contorted fit is itself off)
        res_t, cost_t = fit_frame(self.model, cams, chs, pm, sliding=self.sliding, solver=self.solver,
                                  options=replace(o, max_iterations=4 * o.front_back_iterations, ftol=2e-3, rtol=0.0),
                                  penalty=self.penalty)
        return res_t, cost_t.evaluate(np.asarray(res_t.params))

    def coverage_limit(self) -> float:
        """Coverage below which a limb is taken to be off its silhouette (``TrackerOptions.limb_coverage_drop``
        below the median of the recent frames that passed the gate; none yet: below 1)."""
        ref = float(np.median(self._good_cov)) if self._good_cov else 1.0
        return ref - self.options.limb_coverage_drop

    def _limb_due(self, terms, limit: float, lost: bool) -> bool:
        """Whether the limb check runs (``TrackerOptions``): the legs crossed, or the last check is
        ``limb_every`` frames back and the legs are crossed or, the frame not ``lost``, its coverage is below
        ``limit`` or the last frame's colour check found a forearm or hand lost (``limb_colour_due``)."""
        o = self.options
        self._since_limbs += 1
        self.stride.dead_band_m = o.limb_dead_band * self.model.height_m
        crossed = o.limb_dead_band > 0 and self.stride.update(
            ankle_separation(self.model, np.asarray(terms.pose.params), terms.pose))
        cov = terms.coverage()
        colour = o.limb_colour_due and self._colour_lost
        return crossed or (self._since_limbs >= o.limb_every
                           and (self._legs_crossed(terms)
                                or (not lost and (colour or (np.isfinite(cov) and cov < limit)))))

    def _legs_crossed(self, terms) -> bool:
        """Whether the fit's ankles are crossed by more than ``TrackerOptions.limb_crossed`` × height."""
        lim = self.options.limb_crossed
        return lim is not None and ankle_crossing(self.model, np.asarray(terms.pose.params),
                                                  terms.pose) < -lim * self.model.height_m

    def _limbs(self, cams, chs, res, terms, views):
        """The limb check (``tracker.search.limbs``): ``(res, terms, switched, note)``; ``note``: why the
        frame is not ok ("" if none).  The legs' starts, the left arm's and the right arm's are judged
        apart, each group's best fit against the pose (``exchange_verdict``); the groups clearly better are
        taken together (the best one's fit with the others' limb DOF) and the frame fitted from there."""
        o = self.options
        self._since_limbs = 0
        self.n_limb_checks += 1
        p = np.asarray(res.params, dtype=float)
        v = views()
        kept = hypothesis_cost(self.model, p, terms.rms_px(),
                               self._last_iou if self._last_iou is not None else float(v.score(p)))
        opts = replace(o, max_iterations=o.limb_iterations)
        best = {}
        legs = leg_candidates(self.model, p, crossed=self._legs_crossed(terms))
        for name, start in legs + arm_candidates(self.model, p, self.last_good):
            r, cost = fit_frame(self.model, cams, chs, start, sliding=self.sliding, solver=self.solver, options=opts,
                                penalty=self.penalty)
            q = np.asarray(r.params)
            t = cost.evaluate(q)
            c = hypothesis_cost(self.model, q, t.rms_px(), float(v.score(q)))
            group = f"{name.split('_')[0]} arm" if name.endswith(ARM_STARTS) else "legs"
            if group not in best or c < best[group][0]:
                best[group] = (c, name, q, t)
        chains = dict(side_chains(self.model))
        chains["legs"] = limb_dofs(self.model, LEGS)
        taken, notes = [], []
        for group, (c, name, q, t) in best.items():
            chain = LEGS if group == "legs" else ARMS
            verdict = exchange_verdict(kept, c, chain_joint_distance(self.model, terms.pose, t.pose, chain),
                                       margin=o.limb_margin, same_m=o.limb_same * self.model.height_m)
            if verdict.choice == EXCHANGED:
                taken.append((c, group, q))
            elif verdict.choice == UNSURE:
                notes.append(f"limbs: {name.replace('_', ' ')} fits as well ({c:.2f} vs {kept:.2f})")
        if not taken:
            return res, terms, False, "; ".join(notes)
        taken.sort(key=lambda x: x[0])
        start = taken[0][2].copy()
        for _, group, q in taken[1:]:
            start[chains[group]] = q[chains[group]]
        r, cost = fit_frame(self.model, cams, chs, start, sliding=self.sliding, solver=self.solver, options=o,
                            penalty=self.penalty)
        self.n_limb_switches += 1
        return r, cost.evaluate(np.asarray(r.params)), True, "; ".join(notes)

    def _guard(self, record, cams, chs, images, res, terms, bad, views):
        """The front/back guard's frame (``tracker.fitting.hypotheses``): ``(res, terms, rms, inside,
        bad, swapped, reason, report)``, the mirror's fit when the guard chose it; ``reason``: the guard's
        ("" or why the frame is not ok although the fit is good); ``report``: the mirror's ``(res, terms,
        iou)`` when the open question's evidence favours it (the record reports it), else None."""
        def fit(start, prediction, iterations=None):
            opts = self.options if iterations is None else replace(self.options, max_iterations=int(iterations),
                                                                      ftol=min(self.options.ftol, 2e-3))
            r, cost = fit_frame(self.model, cams, chs, start, prediction=prediction, sliding=self.sliding,
                                solver=self.solver, options=opts, penalty=self.penalty)
            return r, cost.evaluate(np.asarray(r.params))

        iou = (lambda p: float(views().score(p))) if views is not None else None
        out = self.guard.update(t_s=1e-9 * record["timestamp_ns"], cams=cams, chs=[chs[c.name] for c in cams],
                                images=[images[c.name] for c in cams] if images and all(c.name in images for c in cams)
                                else None, res=res, terms=terms, ok=not bad, fit=fit, iou=iou)
        record["front_back"] = self.guard.state
        record["front_back_cues"] = {k: round(float(v), 3) for k, v in out.cues.items()}
        swapped = out.swap is not None
        if swapped:
            res, terms = out.swap
            self._last_iou = None
            bad = self._bad(terms, views)
            self.n_turned += 1
        return res, terms, terms.rms_px(), terms.inside_fraction(), bad, swapped, out.reason, out.report

    def _limb_colour(self, cams, chs, images, params) -> str:
        """The colour check of the distal limbs (``TrackerOptions.limb_colour_margin``): why the frame
        is not ok ("" if it passed, or when there are no images or no learned colours)."""
        o, model = self.options, self.model
        if (o.limb_colour_margin is None or self.guard is None or not self.guard.appearance.learned or not images
                or not all(c.name in images for c in cams)):
            return ""
        parts = _distal_parts(model)
        if not parts.size:
            return ""
        samples = view_colours(model, params, cams, [images[c.name] for c in cams], [chs[c.name] for c in cams],
                               parts=parts)
        trunk = [i for i, n in enumerate(model.part_names) if i not in parts and n != "head"]
        own, other = self.guard.appearance.part_distances(samples, parts, others=trunk)  # (n_cameras, n_parts) each
        seen = np.isfinite(own)
        above = np.count_nonzero(seen & (own - other > o.limb_colour_margin) & (other < o.limb_colour_match), axis=0)
        n_seen = np.count_nonzero(seen, axis=0)
        lost = (n_seen >= o.limb_colour_views) & (above > o.limb_colour_share * n_seen)
        if not lost.any():
            return ""
        names = ", ".join(f"{model.part_names[p].replace('_', ' ')} ({a} of {n} cameras)"
                          for p, a, n in zip(parts[lost], above[lost], n_seen[lost]))
        return f"limb colour: {names} nearer the trunk's, arms' or legs' colour than its own"

    def _uncovered(self, cams, terms, *, passed: bool) -> str:
        """The unexplained-boundary check (``TrackerOptions.uncovered_margin``) of the fit ``terms`` in
        ``cams``: why the frame is not ok ("" if it passed, or without the reverse term); only a frame
        that ``passed`` the gate's other checks can fail it or join the reference."""
        if self.uncovered is None:
            return ""
        root = np.asarray(terms.pose.translation[0], dtype=float)
        depth = np.array([float(np.asarray(c.rotation)[2] @ root + c.translation[2]) for c in cams])
        height_px = np.array([c.matrix[0][0] for c in cams]) * self.model.height_m / np.maximum(depth, 1e-3)
        shares = 1.0 - terms.coverage_per_camera(len(cams), tol_px=self.options.uncovered_tol * height_px)
        return self.uncovered.observe([c.name for c in cams], shares, vouched=passed)

    def step(self, frame_id: int, timestamp_ns: int, chamfer: Mapping[str, object],
             silhouettes: Mapping[str, np.ndarray] | None = None,
             images: Mapping[str, np.ndarray] | None = None) -> dict:
        """Fit one frame set and return its pose record (a JSON-ready dict, DESIGN.md).

        Parameters
        ----------
        frame_id : int
        timestamp_ns : int
        chamfer : mapping str -> ChamferSampler
            Camera name -> sampler; a camera absent this frame is left out.
        silhouettes : mapping str -> ndarray, shape (h, w), optional
            Camera name -> mask; needed for (re)initialisation and the IoU checks.
        images : mapping str -> ndarray, shape (h, w, 3), optional
            Camera name -> BGR frame: the front/back guard's colour cues (``tracker.fitting.hypotheses``).

        Returns
        -------
        dict
            ``frame, timestamp_ns, model, ok, cameras, latency_ms`` and, when solved, ``params, joints,
            rms_px, iterations, inside_fraction, coverage`` (``iou`` when checked); ``reason`` when not ok.
        """
        t0 = self.clock()
        self._since_search += 1
        self._since_ambiguous += 1
        record = {"frame": int(frame_id), "timestamp_ns": int(timestamp_ns), "model": self.model.name}
        unknown = sorted(name for name in chamfer if name not in self.cameras)
        sils = silhouettes if silhouettes is not None else {}
        names = [n for n in self.cameras if n in chamfer and not _silhouette_empty(chamfer[n], sils.get(n))]
        record["cameras"] = len(names)

        def fail(reason: str) -> dict:
            record.update(ok=False, reason=reason, latency_ms=1e3 * (self.clock() - t0))
            self.monitor.update({"ok": False, "reason": reason})
            return record

        if unknown:
            return fail(f"unknown camera(s) {unknown}")
        if not names:
            return fail("no camera with a non-empty silhouette")
        cams = [self.cameras[n] for n in names]
        chs = {n: chamfer[n] for n in names}
        can_search = silhouettes is not None and all(n in silhouettes for n in names)
        start = self.predict(frame_id)
        if start is None:
            if not can_search:
                return fail("no initial pose: pass initial_params, or silhouettes for automatic initialisation")
            try:
                start, mirror = self._search(cams, chamfer, silhouettes, None)
            except ValueError as exc:
                return fail(f"initialisation failed: {exc}")
            self.open_front_back(mirror)
        res, terms, rms, inside = self._fit(cams, chs, start)
        if self._restart_due(start, terms):
            res, terms, rms, inside = self._restart(cams, chs, res, terms, rms, inside)
        built: list = []

        def score_views() -> ScoreViews:
            if not built:
                built.append(ScoreViews(self.model, cams, [silhouettes[n] for n in names], scale=0.5))
            return built[0]

        views = score_views if can_search else None
        self._last_iou = None
        bad = self._bad(terms, views)
        restarted = False
        state = self.monitor.update({"ok": False, "reason": f"poor fit: {bad}"} if bad and not self._soft(bad)
                                    else {"rms_px": rms, "inside_fraction": inside})
        if bad and state.lost and self.recover and can_search:
            try:
                found, mirror = self._search(cams, chamfer, silhouettes, self.last_good)
                res2, terms2, rms2, inside2 = self._fit(cams, chs, found)
                if self.options.recover_full and self.last_good is not None:  # else the search above was it
                    (res2, terms2, rms2, inside2), mirror = self._full_search(cams, chamfer, silhouettes, chs, views,
                                                                            (res2, terms2, rms2, inside2), mirror)
            except ValueError:
                pass
            else:
                bad2 = self._bad(terms2, views)
                if not bad2 or rms2 < rms:
                    res, terms, rms, inside, bad = res2, terms2, rms2, inside2, bad2
                    if not bad or self._soft(bad):
                        self.monitor.reset()
                    restarted = True  # no velocity across a re-initialisation
                    self.open_front_back(mirror)
        if self.options.front_back_every > 0 and views is not None and not restarted and self.guard is None:
            self._since_front_back += 1
            if self._since_front_back >= self.options.front_back_every:
                self._since_front_back = 0
                turned = self._front_back(cams, chs, res, terms, views)
                if turned is not None:
                    res, terms = turned
                    rms, inside = terms.rms_px(), terms.inside_fraction()
                    self._last_iou = None  # the IoU recorded was the other hypothesis's
                    bad = self._bad(terms, views)
                    if not bad or self._soft(bad):
                        self.monitor.reset()
                    self.n_turned += 1
                    restarted = True  # no velocity across the turn
        limbs = ""
        if self.options.limb_every > 0 and views is not None and not restarted:
            limit = self.coverage_limit()
            # a frame that counts towards a lost track is the recovery's unless the legs just crossed
            if self._limb_due(terms, limit, lost=bool(bad) and not self._soft(bad)):
                res, terms, switched, limbs = self._limbs(cams, chs, res, terms, views)
                if switched:
                    rms, inside = terms.rms_px(), terms.inside_fraction()
                    self._last_iou = None
                    bad = self._bad(terms, views)
                    if not bad or self._soft(bad):
                        self.monitor.reset()
                    restarted = True  # no velocity across the switch
            cov = terms.coverage()
            if self.options.limb_flag_coverage and not limbs and np.isfinite(cov) and cov < limit:
                limbs = f"limb off its silhouette: coverage {cov:.3f} < {limit:.3f}"
            if not bad and np.isfinite(cov):
                self._good_cov = (self._good_cov + [float(cov)])[-self.options.rms_window:]
        else:
            self.stride.reset()
        unsure, report = "", None
        if self.guard is not None:
            res, terms, rms, inside, bad, swapped, unsure, report = self._guard(record, cams, chs, images, res, terms,
                                                                                bad, views)
            restarted = restarted or swapped
        # what the record reports; the track goes on from ``bad``
        shown = Verdict() if bad.excused and self._since_ambiguous > self.options.iou_excuse_after_ambiguous else bad
        if self.guard is not None and self.guard.state == AMBIGUOUS:
            self._since_ambiguous = 0
        colour = "" if shown or unsure or limbs else self._limb_colour(cams, chs, images, np.asarray(res.params))
        self._colour_lost = bool(colour)
        uncovered = self._uncovered(cams, terms, passed=not (shown or unsure or limbs or colour))
        # why the frame is not ok: (the record's failed names, its reason), in the record's order
        refusals = ([(list(shown.failed), f"poor fit: {shown}")] if shown else []) + [
            ([name], why) for name, why in (("front_back", unsure), ("limbs", limbs), ("limb_colour", colour),
                                            (UNCOVERED, uncovered)) if why]
        self.last_result = res
        # the pose reported: the tracked one, or the mirror the open question's evidence favours (the frame's
        # reason and failed limits stay the tracked pose's; its quality figures are the reported one's)
        if report is None:
            r_res, r_terms, r_iou, r_rms, r_inside = res, terms, self._last_iou, rms, inside
        else:
            (r_res, r_terms, r_iou), r_rms, r_inside = report, report[1].rms_px(), report[1].inside_fraction()
        joints = joint_centre_array(self.model, r_terms.pose)
        record.update(
            ok=not refusals, params=[float(v) for v in r_res.params],
            joints={n: [float(v) for v in joints[i]] for i, n in enumerate(self.model.joint_names)},
            rms_px=_finite(r_rms), iterations=int(r_res.iterations),
            inside_fraction=_finite(r_inside), coverage=_finite(r_terms.coverage()),
        )
        if report is not None:
            record["front_back_reported"] = "mirror"
        if r_iou is not None:
            record["iou"] = r_iou
        self._since_iou = 0 if self._last_iou is not None else self._since_iou + 1
        self._last_bad = bool(bad)
        if refusals:
            record["reason"] = "; ".join(why for _, why in refusals) + (
                "" if report is None else "; the mirror reported (the limits above are the tracked pose's)")
            record["failed"] = [name for names, _ in refusals for name in names]
        if bad and not self._soft(bad):
            self.params = np.array(res.params)  # next start; the velocity reference is dropped
            self.previous = None
            self._frames = (self._frames[1], int(frame_id))
        else:
            # no velocity across a re-initialisation or out of a suspect fit (hop: 3 frames of 120
            # after the landing; extrapolating from them drifted 15-20 mm for ~20 frames)
            self.previous = None if restarted or self._suspect(terms) or bad else self.params
            self.params = np.array(res.params)
            self._frames = (self._frames[1], int(frame_id))
            self.last_good = self.params
            if np.isfinite(rms):
                self._good_rms = (self._good_rms + [float(rms)])[-self.options.rms_window:]
        record["latency_ms"] = 1e3 * (self.clock() - t0)
        return record


def _distal_parts(model: BodyModel) -> np.ndarray:
    """Indices of the parts the colour check samples: the forearms and hands."""
    return np.array([i for i, n in enumerate(model.part_names) if n.endswith(("forearm", "hand"))], int)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None
