"""Loss detection and recovery: flag frames the fit lost, re-initialise from the visual hull.

**Detection** (``LossMonitor``): a frame is *bad* when its RMS chamfer residual exceeds
``max_rms_px`` or the fraction of predicted contour points on the silhouettes falls below
``min_inside_fraction`` (a drifted model sticks out of the silhouettes).  ``patience``
consecutive bad frames make the track *lost*; one good frame makes it ``ok`` again.

**Recovery** (``recover``): the subject may be in any pose, so instead of the T/A reference
poses of ``tracker.search.initialise`` the search starts from the last good pose, in two stages.

The cheap stage (``local_search``): the last good pose, moved onto the hull and turned to
``n_headings`` headings, the best by IoU limb-searched and refined once by staged LM; its
front/back mirror refined too where the silhouettes cannot tell them apart.  Accepted when the
mean silhouette IoU reaches ``accept_iou`` (or what the views allow, see ``recover``); otherwise
the full search:

1. the last good pose moved onto the hull at ``n_headings`` headings
   (``tracker.search.candidates.hull_placements``), with the reference-pose hypotheses of
   ``pose_candidates`` and the last pose's joint angles among them;
2. a greedy limb search (``limb_search``) on the best, then the staged LM of
   ``tracker.search.refine.refine`` (a weaker prior than initialisation's: the hypothesis is
   rougher); a last limb search on the winner catches a limb the first pass left behind;
3. the winner and its front/back mirror (``tracker.search.mirror``), both limb-searched and refined
   fully, the better kept: steps 2-3 are ``tracker.search.initialise.search_candidates``.

How often the cheap stage is taken and what it saves: docs/tuning.md, "Recovery".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from tracker.body.model import BodyModel
from tracker.fitting.sampler import ChamferViews
from tracker.search.candidates import (estimate_height, feet_direction, hull_placements, limb_search,
                                       pose_candidates)
from tracker.search.hull import VoxelHull
from tracker.search.initialise import SearchOptions, search_candidates, search_views
from tracker.search.mirror import front_back_cost, joints_at_limits, mirror_params, pelvis_heading
from tracker.search.refine import InitResult, refine
from tracker.search.scoring import ScoreViews, prepare_inputs

__all__ = ["LossMonitor", "LossState", "recover", "local_search", "local_starts", "local_refine", "rejoin"]

OK, SUSPECT, LOST = "ok", "suspect", "lost"


@dataclass(frozen=True)
class LossState:
    """What the monitor concluded for a frame.

    Attributes
    ----------
    state : str
        ``"ok"``, ``"suspect"`` (bad, fewer than ``patience`` in a row) or ``"lost"``.
    bad_frames : int
        Consecutive bad frames so far.
    reason : str
        Why the frame is bad ("" when good).
    """

    state: str
    bad_frames: int
    reason: str = ""

    @property
    def lost(self) -> bool:
        return self.state == LOST


def _quality(quality, name: str) -> float:
    """``rms_px`` / ``inside_fraction`` from a pose record (mapping), a ``CostTerms`` or any object."""
    if isinstance(quality, Mapping):
        v = quality.get(name)
    else:
        v = getattr(quality, name, None)
        v = v() if callable(v) else v
    return float("nan") if v is None else float(v)


class LossMonitor:
    """Flags lost tracking from per-frame quality.

    Parameters
    ----------
    max_rms_px : float
        RMS chamfer residual above which a frame is bad, pixels.
    min_inside_fraction : float
        Fraction of contour points on the silhouettes below which a frame is bad.
    patience : int
        Consecutive bad frames before the track is lost (>= 1).
    """

    def __init__(self, *, max_rms_px: float = 6.0, min_inside_fraction: float = 0.6, patience: int = 3) -> None:
        if not max_rms_px > 0:
            raise ValueError(f"max_rms_px: expected > 0, got {max_rms_px}")
        if not 0.0 <= min_inside_fraction <= 1.0:
            raise ValueError(f"min_inside_fraction: expected in [0, 1], got {min_inside_fraction}")
        if int(patience) < 1:
            raise ValueError(f"patience: expected >= 1, got {patience}")
        self.max_rms_px = float(max_rms_px)
        self.min_inside_fraction = float(min_inside_fraction)
        self.patience = int(patience)
        self.bad_frames = 0

    def reset(self) -> None:
        """Forget the bad frames counted so far."""
        self.bad_frames = 0

    def update(self, quality) -> LossState:
        """Take one frame's quality and say whether the track is ok, suspect or lost.

        Parameters
        ----------
        quality : mapping, CostTerms or object
            A pose record (``rms_px``, ``inside_fraction``, optional ``ok`` and ``reason``), a
            ``tracker.fitting.cost.CostTerms``, or an object with those attributes.

        Returns
        -------
        LossState
        """
        rms = _quality(quality, "rms_px")
        inside = _quality(quality, "inside_fraction")
        reasons = []
        if isinstance(quality, Mapping) and quality.get("ok") is False and "reason" in quality \
                and not str(quality["reason"]).startswith("lost"):
            reasons.append(str(quality["reason"]))
        if not np.isfinite(rms) or rms > self.max_rms_px:
            reasons.append(f"rms {rms:.2f} px > {self.max_rms_px:g}")
        if not np.isfinite(inside) or inside < self.min_inside_fraction:
            reasons.append(f"{100 * inside:.0f}% of contour inside < {100 * self.min_inside_fraction:.0f}%")
        if not reasons:
            self.bad_frames = 0
            return LossState(OK, 0)
        self.bad_frames += 1
        state = LOST if self.bad_frames >= self.patience else SUSPECT
        return LossState(state, self.bad_frames, "; ".join(reasons))


# ----------------------------------------------------------------------------- search
def local_search(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, views: ScoreViews,
                 hull: VoxelHull, last: np.ndarray, *, n_headings: int = 12, accept_iou: float = 0.87,
                 min_inside_fraction: float = 0.8, max_iterations: int = 8, n_samples: int = 6,
                 prior_rad: float = 50.0, reverse_weight: float = 1.0, mirror_check: bool = True,
                 mirror_margin: float = 0.1) -> InitResult | None:
    """The cheap first stage of ``recover``: a local re-fit seeded from the last good pose.

    The last good pose as it was, and moved onto the hull at ``n_headings`` headings, is scored by
    IoU; the best is refined by ``local_refine``.

    Parameters
    ----------
    model, cameras, chamfer, views, hull
        As ``local_refine``.
    last : ndarray, shape (n_params,)
        The last good pose.
    n_headings : int
        Turns about the vertical tried on the hull.
    accept_iou, min_inside_fraction, max_iterations, n_samples, prior_rad, reverse_weight, mirror_check, mirror_margin
        As ``local_refine``.

    Returns
    -------
    InitResult or None
        As ``local_refine``.
    """
    poses = local_starts(model, hull, last, n_headings)
    scores = views.scores(poses)
    best = int(np.argmax(scores))  # the first of equal ones
    return local_refine(model, cameras, chamfer, views, hull, poses[best], float(scores[best]), accept_iou=accept_iou,
                        min_inside_fraction=min_inside_fraction, max_iterations=max_iterations, n_samples=n_samples,
                        prior_rad=prior_rad, reverse_weight=reverse_weight, mirror_check=mirror_check,
                        mirror_margin=mirror_margin)


def local_starts(model: BodyModel, hull: VoxelHull, last: np.ndarray, n_headings: int) -> list[np.ndarray]:
    """``last`` as it is, then moved onto the hull at ``n_headings`` headings: ``local_search``'s starts.

    Returns
    -------
    list of ndarray, shape (n_params,)
        ``1 + n_headings`` poses.
    """
    return [last] + [p for _, _, p in hull_placements(model, last, hull, n_headings)]


def local_refine(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, views: ScoreViews,
                 hull: VoxelHull, start: np.ndarray, score: float, *, accept_iou: float = 0.87,
                 min_inside_fraction: float = 0.8, max_iterations: int = 8, n_samples: int = 6,
                 prior_rad: float = 50.0, reverse_weight: float = 1.0, mirror_check: bool = True,
                 mirror_margin: float = 0.1) -> InitResult | None:
    """One start of the cheap recovery refined: a limb search, one staged LM, the front/back check.

    ``start`` gets a limb search and one staged LM refinement (root, joints, everything), and the
    lower ``front_back_cost`` of it and its mirror is kept.

    Parameters
    ----------
    model, cameras, views, hull
        The frame set's model, cameras, IoU scoring views and visual hull.
    chamfer : mapping str -> ChamferSampler
    start : ndarray, shape (n_params,)
        The start pose (within the limits).
    score : float
        Its mean silhouette IoU on ``views``.
    accept_iou, min_inside_fraction : float
        Least mean IoU and least fraction of contour points on the silhouettes of an accepted result.
    max_iterations, n_samples, prior_rad, reverse_weight : int, int, float, float
        ``refine``: LM steps per stage, contour points per side, joint-angle prior (px² per rad²),
        weight of the silhouette -> model term.
    mirror_check, mirror_margin : bool, float
        Refine the mirror too where its IoU is within ``mirror_margin`` of the result's.

    Returns
    -------
    InitResult or None
        Label ``"local/kept"`` or ``"local/mirrored"``; None when not accepted.
    """
    start, _ = limb_search(model, views, start, score)
    x, terms = refine(model, cameras, chamfer, start, max_iterations=max_iterations, n_samples=n_samples,
                      prior_rad=prior_rad, reverse_weight=reverse_weight)
    iou = views.score(x)
    best = (front_back_cost(terms.rms_px(), iou, joints_at_limits(model, x)), "kept", x, terms, iou)
    other = None  # the other front/back hypothesis, when refined
    if mirror_check:  # front or back: refined only where the mirror explains the silhouettes about as well
        m = model.clamp(mirror_params(model, x))
        if views.score(m) >= iou - mirror_margin:
            xm, terms_m = refine(model, cameras, chamfer, m, max_iterations=max_iterations, n_samples=n_samples,
                                 prior_rad=prior_rad, reverse_weight=reverse_weight)
            iou_m = views.score(xm)
            cost_m = front_back_cost(terms_m.rms_px(), iou_m, joints_at_limits(model, xm))
            other = xm
            if cost_m < best[0]:
                other, best = x, (cost_m, "mirrored", xm, terms_m, iou_m)
    _, label, x, terms, iou = best
    if not (iou >= accept_iou and terms.inside_fraction() >= min_inside_fraction):
        return None
    h = pelvis_heading(model, x)
    return InitResult(params=x, score=iou, rms_px=terms.rms_px(), inside_fraction=terms.inside_fraction(),
                      heading_rad=float(np.arctan2(h[1], h[0])), label=f"local/{label}",
                      height_m=estimate_height(hull, model), candidates=views.n_scored, hull=hull, mirror=other)


def recover(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
            chamfer: ChamferViews | None, last_good_params, *,
            options: SearchOptions = SearchOptions.for_recovery()) -> InitResult:
    """Re-initialise a lost track from the hull, seeded from the last good pose; any pose.

    The cheap ``local_search`` (with ``options.local``) is accepted at a mean silhouette IoU of
    ``options.accept_iou`` or of ``options.iou_margin`` below what a correct pose reaches on these
    views (``ScoreViews.expected_iou``), whichever is lower: a caller that knows what good frames
    reach on its segmentation can pass that less a few hundredths.  The full search runs only when
    the local stage fails.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    silhouettes : mapping str -> ndarray, shape (h, w)
        Camera name -> mask, non-zero = body.
    chamfer : mapping str -> ChamferSampler, or None
        Camera name -> sampler; None: built from the silhouettes.
    last_good_params : ndarray, shape (n_params,)
        The last good pose; must be finite.
    options : SearchOptions
        Default ``SearchOptions.for_recovery()``.

    Returns
    -------
    InitResult

    Raises
    ------
    ValueError
        Bad views (the camera named), a bad last pose, or no common volume.
    """
    inputs = prepare_inputs(model, cameras, silhouettes, chamfer)
    last = np.asarray(last_good_params, dtype=float)
    if last.shape != (model.n_params,) or not np.all(np.isfinite(last)):
        raise ValueError(f"last_good_params: expected a finite array of shape ({model.n_params},)")
    last = model.clamp(last)
    hull, views = search_views(model, inputs, options, caller="recover")
    if options.local:
        accept = min(options.accept_iou, views.expected_iou() - options.iou_margin)  # lower views score lower
        res = local_search(model, inputs.cameras, inputs.chamfer, views, hull, last, n_headings=options.n_headings,
                           accept_iou=accept, mirror_check=options.front_back)
        if res is not None:
            return res
    cands = hull_placements(model, last, hull, options.n_headings) + pose_candidates(
        model, hull, n_headings=options.n_headings, arm_abduction_deg=options.arm_abduction_deg, hint=last)
    facing = feet_direction(hull) if options.use_feet else None
    return search_candidates(model, inputs, hull, views, cands, options, facing=facing)


def rejoin(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
           chamfer: ChamferViews | None, seeds: Sequence[np.ndarray], *,
           options: SearchOptions = SearchOptions.for_recovery(), n_headings: int | None = None,
           accept_iou: float | None = None, min_inside_fraction: float = 0.8) -> InitResult | None:
    """The cheap stage of ``recover`` alone, from several seeds: a lost track rejoins or None.

    Every finite seed (e.g. the last good pose, the tracker's last fit, a stale search result to
    bring onto this frame set) gives ``local_search``'s starts, all scored by IoU together; the
    seeds' best starts are then refined (``local_refine``) best first, and the first result that
    passes the gate is returned, so a rejoin that succeeds usually refines one start.  Its cost is
    bounded (one hull, at most one limb search and two staged refinements per seed), so a caller
    can run it between frames.

    Parameters
    ----------
    model, cameras, silhouettes, chamfer
        As ``recover``.
    seeds : sequence of ndarray, shape (n_params,)
        Start poses; non-finite ones are skipped.  Of seeds whose best starts score equally, the
        earlier is refined first.
    options : SearchOptions
        ``accept_iou``, ``iou_margin``, ``front_back``, the hull and scoring views.
    n_headings : int, optional
        Headings tried per seed (default ``options.n_headings``).
    accept_iou, min_inside_fraction : float or None, float
        Least mean IoU and fraction of contour points on the silhouettes of an accepted result
        (``accept_iou`` None: ``recover``'s own acceptance; a tracker passes its own quality gate).

    Returns
    -------
    InitResult or None
        ValueError as ``recover`` (bad views, no common volume).
    """
    inputs = prepare_inputs(model, cameras, silhouettes, chamfer)
    hull, views = search_views(model, inputs, options, caller="rejoin")
    sure = min(options.accept_iou, views.expected_iou() - options.iou_margin)
    accept = sure if accept_iou is None else min(float(accept_iou), sure)
    n_headings = options.n_headings if n_headings is None else int(n_headings)
    starts = [local_starts(model, hull, model.clamp(np.asarray(seed, dtype=float)), n_headings) for seed in seeds
              if np.shape(seed) == (model.n_params,) and np.all(np.isfinite(seed))]
    if not starts:
        return None
    scores = views.scores([p for poses in starts for p in poses]).reshape(len(starts), -1)
    best = np.argmax(scores, axis=1)  # per seed, the first of equal ones
    tried: list[np.ndarray] = []
    for k in np.argsort(-scores[np.arange(len(starts)), best], kind="stable"):
        start = starts[k][best[k]]
        if any(np.array_equal(start, t) for t in tried):  # two seeds, one start: refined once
            continue
        tried.append(start)
        res = local_refine(model, inputs.cameras, inputs.chamfer, views, hull, start, float(scores[k, best[k]]),
                           accept_iou=accept, min_inside_fraction=min_inside_fraction, mirror_check=options.front_back)
        if res is not None:
            return res
    return None
