"""Refining pose hypotheses: staged bounded LM on the chamfer cost, the best of several, bent elbows.

``refine`` runs robust, bounded Levenberg–Marquardt (``tracker.fitting.solver``) on the chamfer cost
(``tracker.fitting.cost``) in stages: the root first, then the joints, then everything (IJCV'08 §6),
with a weak prior holding the joint angles towards the hypothesis.  ``refine_best`` refines the
candidates that score best by silhouette IoU and keeps the refined one with the best IoU (the
chamfer cost is model -> image only, so it cannot tell a model whose limb hides inside the body from
the right one).  ``elbow_search`` tries bent elbows, which the silhouettes hide when a forearm lies
in front of the trunk but the internal edges show.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from capture.camera import Camera
from tracker.body.model import JOINT_ROTATION, BodyModel
from tracker.fitting.cost import ChamferCost, CostTerms
from tracker.fitting.sampler import ChamferViews, in_camera_order
from tracker.fitting.solver import levenberg_marquardt
from tracker.search.candidates import estimate_height
from tracker.search.hull import VoxelHull
from tracker.search.scoring import ScoreViews

__all__ = ["InitResult", "refine", "refine_best", "elbow_search", "ELBOW_SEARCH_DEG", "Prepare"]

#: ``prepare(params, iou) -> (params, iou)``: a cheap search run on a hypothesis before it is
#: refined (e.g. ``tracker.search.candidates.limb_search`` bound to its views).
Prepare = Callable[[np.ndarray, float], tuple[np.ndarray, float]]

#: Elbow hypotheses tried by ``elbow_search``, degrees, per DOF name suffix: the forearm bent
#: with the upper arm twisted either way (the bend points forwards, outwards or inwards), and bent
#: with the arm hanging straight down.
ELBOW_SEARCH_DEG = ({"forearm.flexion": 45, "upper_arm.twist": 30}, {"forearm.flexion": 45, "upper_arm.twist": -30},
                    {"forearm.flexion": 45, "upper_arm.twist": 0, "upper_arm.abduction": -100},
                    {"forearm.flexion": 90, "upper_arm.twist": 30})


@dataclass(frozen=True, eq=False)
class InitResult:
    """Outcome of a pose search.  ``np.asarray(result)`` gives ``params``.

    Attributes
    ----------
    params : ndarray, shape (n_params,)
        The pose.
    score : float
        Mean silhouette IoU of that pose (1 = perfect).
    rms_px : float
        RMS chamfer residual at ``params``, pixels (NaN if no refinement ran).
    inside_fraction : float
        Fraction of contour points on the silhouettes.
    heading_rad : float
        The search heading it came from, radians.
    label : str
        Which hypothesis won (``"T"``, ``"A"``, ``"T/A"`` = left T, right A, ``"hint"``, ``"last"``,
        ``"local"``; ``"+elbows"`` when ``elbow_search`` changed the pose), then ``"/kept"`` or
        ``"/mirrored"`` after the front/back check (``tracker.search.mirror.resolve_front_back``).
    height_m : float
        The subject height the hull suggests, metres.
    candidates : int
        Poses scored.
    hull : VoxelHull or None
        The visual hull used.
    mirror : ndarray, shape (n_params,), or None
        The other front/back hypothesis, refined as far as ``params`` (None when none was refined).
    """

    params: np.ndarray
    score: float
    rms_px: float
    inside_fraction: float
    heading_rad: float
    label: str
    height_m: float
    candidates: int
    hull: VoxelHull | None = field(default=None, repr=False)
    mirror: np.ndarray | None = field(default=None, repr=False)

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.params, dtype=dtype)

    def clamped_mirror(self, model) -> np.ndarray | None:
        """``mirror`` within ``model``'s joint limits (``BodyModel.clamp``), or None without one."""
        return None if self.mirror is None else model.clamp(np.asarray(self.mirror, dtype=float))


def _subset_fun(fun, x_full: np.ndarray, idx: np.ndarray):
    """Restrict ``fun(x, jacobian) -> (r, J)`` to the parameters ``idx``."""

    def f(xs, jacobian):
        x = x_full.copy()
        x[idx] = xs
        r, J = fun(x, jacobian)
        if J is None:
            return r, None
        return r, (J.columns(idx) if hasattr(J, "columns") else J[:, idx])

    return f


def _stages(model: BodyModel) -> list[np.ndarray]:
    root = np.flatnonzero(model.param_kind != JOINT_ROTATION)
    joints = np.flatnonzero(model.param_kind == JOINT_ROTATION)
    return [root, joints, np.arange(model.n_params)]


def refine(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, params: np.ndarray, *,
           stages: Sequence[np.ndarray] | None = None, max_iterations: int = 10, n_samples: int = 6,
           f_scale: float = 5.0, truncate_px: float = 30.0, prior_rad: float = 500.0,
           reverse_weight: float = 0.0, ftol: float = 1e-3) -> tuple[np.ndarray, CostTerms]:
    """Staged bounded LM on the chamfer cost from ``params``.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    chamfer : mapping str -> ChamferSampler
        Camera name -> sampler (``tracker.fitting.sampler``).
    params : ndarray, shape (n_params,)
        The start; clamped to the limits.
    stages : sequence of ndarray of int, optional
        Parameter indices refined in turn (default: root, joints, everything).
    max_iterations, n_samples, ftol : int, int, float
        LM steps per stage, contour points per side of a part, relative cost change to stop at.
    f_scale, truncate_px : float
        Huber loss scale and distance truncation, pixels.
    prior_rad : float
        Weight (px² per rad²) holding the joint angles towards ``params``: a straight T-pose arm
        cannot tell clavicle from shoulder rotation, and the hypothesis is the better guess.
    reverse_weight : float
        Weight of the silhouette -> model term (0: off); it pulls a limb back onto silhouette it
        left uncovered.

    Returns
    -------
    params : ndarray, shape (n_params,)
    terms : CostTerms
        The cost at ``params``.
    """
    cost = ChamferCost(model, cameras, in_camera_order(chamfer, cameras), n_samples=n_samples,
                       truncate_px=truncate_px, reverse_weight=reverse_weight, reverse_samples=150,
                       reverse_min_px=4.0)
    fun = cost.residual_fn(compact=True, structured=True)
    x = model.clamp(np.asarray(params, dtype=float))
    x0 = x.copy()
    weight = np.where(model.param_kind == JOINT_ROTATION, float(prior_rad), 0.0)
    for idx in _stages(model) if stages is None else stages:
        idx = np.asarray(idx, dtype=int)
        res = levenberg_marquardt(_subset_fun(fun, x, idx), x[idx], lower=model.lower[idx], upper=model.upper[idx],
                                  prior=x0[idx], prior_weight=weight[idx], loss="huber", f_scale=f_scale,
                                  max_iterations=max_iterations, ftol=ftol)
        x = x.copy()
        x[idx] = res.params
    return x, cost.evaluate(x)


def refine_best(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, views: ScoreViews,
                hull: VoxelHull, candidates: Sequence[tuple[str, float, np.ndarray]], *, keep: int = 2,
                max_iterations: int = 10, prepare: Prepare | None = None, prior_rad: float = 500.0,
                polish: bool = False) -> InitResult:
    """Refine the candidates that score best by IoU and return the refined one with the best IoU.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    chamfer : mapping str -> ChamferSampler
    views : ScoreViews
    hull : VoxelHull
        Where the candidates stand (recorded in the result, and its height).
    candidates : sequence of (label, heading_rad, params)
        As ``tracker.search.candidates.pose_candidates`` gives them.
    keep : int
        Candidates refined (the best by IoU).
    max_iterations : int
        LM steps per stage of ``refine``.
    prepare : callable, optional
        ``prepare(params, iou) -> (params, iou)`` run on each kept candidate before refining.
    prior_rad : float
        ``refine``'s joint-angle prior, px² per rad².
    polish : bool
        Run ``prepare`` once more on the refined winner and refine again if that raised its IoU
        (a limb the first pass left behind).

    Returns
    -------
    InitResult
    """
    scores = views.scores([p for _, _, p in candidates])
    best = None
    for i in np.argsort(-scores, kind="stable")[: max(1, int(keep))]:
        label, psi, p0 = candidates[i]
        if prepare is not None:
            p0, _ = prepare(p0, scores[i])
        p, terms = refine(model, cameras, chamfer, p0, max_iterations=max_iterations, prior_rad=prior_rad)
        s = views.score(p)
        if best is None or s > best[0]:
            best = (s, p, terms, label, psi)
    s, p, terms, label, psi = best
    if polish and prepare is not None:
        p2, s2 = prepare(p, s)
        if s2 > s:
            p2, terms2 = refine(model, cameras, chamfer, p2, max_iterations=max_iterations, prior_rad=prior_rad)
            s2 = views.score(p2)
            if s2 > s:
                s, p, terms = s2, p2, terms2
    return InitResult(params=p, score=s, rms_px=terms.rms_px(), inside_fraction=terms.inside_fraction(),
                      heading_rad=psi, label=label, height_m=estimate_height(hull, model),
                      candidates=views.n_scored, hull=hull)


def elbow_search(model: BodyModel, cameras: Sequence[Camera], chamfer: ChamferViews, views: ScoreViews,
                 params: np.ndarray, *, options=ELBOW_SEARCH_DEG, max_iterations: int = 8,
                 iou_weight: float = 10.0) -> tuple[np.ndarray, float]:
    """Arms bent at the elbow, which the silhouettes hide.

    A forearm bent in front of the trunk lies inside the trunk's outline, so the IoU of the limb
    search cannot see it; the internal edges of the chamfer cost can.  For each arm in turn every
    hypothesis of ``options`` is refined fully (``refine``: all DOF, the silhouette -> model term
    on) and kept when it lowers RMS chamfer residual + ``iou_weight`` × (1 - IoU).

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    chamfer : mapping str -> ChamferSampler
    views : ScoreViews
    params : ndarray, shape (n_params,)
    options : sequence of dict str -> float
        Angle sets, degrees per DOF name suffix, set on the pose with the other DOF kept
        (``ELBOW_SEARCH_DEG``).
    max_iterations : int
        LM steps of each refinement.
    iou_weight : float
        Weight of 1 - IoU against the RMS residual (pixels).

    Returns
    -------
    params : ndarray, shape (n_params,)
    cost : float
        RMS residual (pixels) + ``iou_weight`` × (1 - IoU) of ``params``.
    """
    cost = ChamferCost(model, cameras, in_camera_order(chamfer, cameras), n_samples=6, truncate_px=30.0,
                       reverse_weight=1.0, reverse_samples=150, reverse_min_px=4.0)

    def score(p: np.ndarray, terms=None) -> float:
        terms = cost.evaluate(p) if terms is None else terms
        return float(terms.rms_px() + iou_weight * (1.0 - views.score(p)))

    x = model.clamp(np.asarray(params, dtype=float))
    best = score(x)
    everything = [np.arange(model.n_params)]
    for side in ("left", "right"):
        for opt in options:
            y = x.copy()
            for suffix, deg in opt.items():
                name = f"{side}_{suffix}"
                if name in model.param_names:
                    y[model.param_names.index(name)] = np.radians(deg)
            y, terms = refine(model, cameras, chamfer, model.clamp(y), stages=everything, max_iterations=max_iterations,
                              n_samples=6, prior_rad=30.0, reverse_weight=1.0)
            s = score(y, terms)
            if s < best:
                x, best = y, s
    return x, best
