"""Loss detection and recovery: flag frames the fit lost, re-initialise from the visual hull.

**Detection** (``LossMonitor``): a frame is *bad* when its RMS chamfer residual exceeds
``max_rms_px`` or the fraction of predicted contour points on the silhouettes falls below
``min_inside_fraction`` (a drifted model sticks out of the silhouettes).  ``patience``
consecutive bad frames make the track *lost*; one good frame makes it ``ok`` again.

**Recovery** (``recover``): the subject may be in any pose, so instead of the T/A reference
poses of ``tracker.search.initialise`` the search starts from the last good pose, in two stages.

The cheap stage (``local_search``; ``bench/recovery.py``, hop clip with 5-10 frames dropped,
6 cameras at 320x240 or 640x480: 0.2 s of one core instead of 1.2-1.5 s, taken in 25-30 of 35
cases, as often within 30 mm of the truth as the full search): the last good pose, moved onto
the hull and turned to ``n_headings`` headings, the best by IoU limb-searched and refined once
by staged LM; its front/back mirror refined too where the silhouettes cannot tell them apart.
Accepted when the mean silhouette IoU reaches ``accept_iou`` (or what the views allow, see
``recover``); otherwise the full search:

1. the last good pose is moved onto the hull (its volume centroid onto the hull's, horizontally)
   and turned about the vertical through it to ``n_headings`` headings; the best by silhouette
   IoU is kept together with the reference-pose hypotheses of ``pose_candidates``;
2. a greedy limb search (``limb_search``): for each chain (arms, legs, trunk) alternative angle
   sets (the reference pose, half-way to it, the mirror of the other side, and the canonical
   poses of ``ARM_SEARCH_DEG`` / ``LEG_SEARCH_DEG``) are scored by IoU with the rest fixed;
3. the best ``keep`` hypotheses are refined by the staged LM of ``tracker.search.initialise.refine``
   (a weaker prior than initialisation's: the hypothesis is rougher) and the best IoU wins;
   a last limb search on the winner, refined again if it raised the IoU, catches a limb the
   first pass left behind;
4. the winner and its front/back mirror (``tracker.search.mirror``) are both limb-searched and refined
   fully, and the better kept.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera, matrix_to_rodrigues
from tracker.search.hull import visual_hull
from tracker.search.initialise import (InitResult, ScoreViews, estimate_height, pose_candidates, prepare_inputs, refine,
                                refine_best)
from tracker.body.kinematics import forward, so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.imaging.render import body_points

__all__ = ["LossMonitor", "LossState", "recover", "local_search", "limb_chains", "limb_search", "turn_about_vertical",
           "ARM_SEARCH_DEG", "LEG_SEARCH_DEG"]

OK, SUSPECT, LOST = "ok", "suspect", "lost"


@dataclass(frozen=True)
class LossState:
    """What the monitor concluded for a frame.

    state : ``"ok"``, ``"suspect"`` (bad, fewer than ``patience`` in a row) or ``"lost"``;
    bad_frames : consecutive bad frames so far; reason : why the frame is bad ("" when good).
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
    max_rms_px : RMS chamfer residual above which a frame is bad (pixels)
    min_inside_fraction : fraction of contour points on the silhouettes below which a frame is bad
    patience : consecutive bad frames before the track is lost (>= 1)
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
        self.bad_frames = 0

    def update(self, quality) -> LossState:
        """Take one frame's quality: a pose record (``rms_px``, ``inside_fraction``, optional
        ``ok``), a ``tracker.fitting.cost.CostTerms``, or an object with those attributes."""
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


# ----------------------------------------------------------------------------- hypotheses
def limb_chains(model: BodyModel) -> dict[str, np.ndarray]:
    """Joint-parameter indices per chain: ``left_arm``, ``right_arm``, ``left_leg``, ``right_leg``, ``trunk``."""
    groups = {"left_arm": ("left_clavicle", "left_upper_arm", "left_forearm", "left_hand"),
              "right_arm": ("right_clavicle", "right_upper_arm", "right_forearm", "right_hand"),
              "left_leg": ("left_thigh", "left_shank", "left_foot"),
              "right_leg": ("right_thigh", "right_shank", "right_foot")}
    out = {}
    joint = model.param_kind == JOINT_ROTATION
    taken = np.zeros(model.n_params, bool)
    for chain, parts in groups.items():
        pidx = [model.part_names.index(p) for p in parts if p in model.part_names]
        sel = joint & np.isin(model.param_part, pidx)
        out[chain] = np.flatnonzero(sel)
        taken |= sel
    out["trunk"] = np.flatnonzero(joint & ~taken)
    return out


def _mirror_pairs(model: BodyModel) -> dict[int, int]:
    """Parameter index -> the same DOF on the other side (``left_*`` <-> ``right_*``)."""
    out = {}
    for i, n in enumerate(model.param_names):
        for a, b in (("left_", "right_"), ("right_", "left_")):
            if n.startswith(a) and n.replace(a, b, 1) in model.param_names:
                out[i] = model.param_names.index(n.replace(a, b, 1))
    return out


def turn_about_vertical(model: BodyModel, params: np.ndarray, angle_rad: float, pivot: np.ndarray) -> np.ndarray:
    """The pose ``params`` turned by ``angle_rad`` about the vertical line through ``pivot`` (3,)."""
    p = np.array(params, dtype=float)
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    r_idx = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    Rz = so3_exp(np.array([0.0, 0.0, angle_rad]))
    R = Rz @ so3_exp(p[r_idx])
    p[t_idx] = pivot + Rz @ (p[t_idx] - pivot)
    p[r_idx] = matrix_to_rodrigues(R)
    return p


def _centroid(model: BodyModel, params: np.ndarray) -> np.ndarray:
    return body_points(model, forward(model, params), n_theta=8, n_z=2).reshape(-1, 3).mean(0)


#: Canonical limb poses tried by the limb search, degrees, per DOF name suffix (other DOF of the
#: chain 0).  The models mirror the right side's axes, so one table serves both sides.
ARM_SEARCH_DEG = tuple({"upper_arm.abduction": a, "upper_arm.flexion": f}
                      for a in (-80, -45, 0, 35, 70) for f in (-40, 0, 50) if (a, f) != (0, 0)) + (
                 {"upper_arm.abduction": -45, "forearm.flexion": 70}, {"upper_arm.flexion": 60, "forearm.flexion": 70})
LEG_SEARCH_DEG = ({"thigh.flexion": 30}, {"thigh.flexion": -15}, {"thigh.abduction": 20},
                 {"thigh.flexion": 45, "shank.flexion": 60}, {"shank.flexion": 45})


def _canonical(model: BodyModel, chain: str, idx: np.ndarray, arm_poses, leg_poses) -> list[np.ndarray]:
    side = chain.split("_")[0]
    table = arm_poses if chain.endswith("arm") else leg_poses if chain.endswith("leg") else ()
    out = []
    for pose in table:
        vals = np.zeros(idx.size)
        for suffix, deg in pose.items():
            name = f"{side}_{suffix}"
            if name in model.param_names and model.param_names.index(name) in idx:
                vals[list(idx).index(model.param_names.index(name))] = np.radians(deg)
        out.append(vals)
    return out


def limb_search(model: BodyModel, views: ScoreViews, params: np.ndarray, score: float, *,
                arm_poses=ARM_SEARCH_DEG, leg_poses=LEG_SEARCH_DEG) -> tuple[np.ndarray, float]:
    """Greedy per-chain search, scored by IoU with the rest fixed: the chain's current angles
    halved, zeroed, mirrored from the other side, and the canonical ``arm_poses`` / ``leg_poses``
    (see ``ARM_SEARCH_DEG``); ``score`` is the IoU of ``params``.  Returns (params, score)."""
    mirror = _mirror_pairs(model)
    x = params.copy()
    for chain, idx in limb_chains(model).items():
        if idx.size == 0:
            continue
        options = [np.zeros(idx.size), 0.5 * x[idx]] + _canonical(model, chain, idx, arm_poses, leg_poses)
        if all(i in mirror for i in idx):
            options.append(x[[mirror[i] for i in idx]])
        moved = model.affects[:, idx].any(axis=1)  # the chain's parts and everything below them
        base = views.render(x, np.flatnonzero(~moved))  # the rest is drawn once per chain
        for vals in options:
            y = x.copy()
            y[idx] = vals
            y = model.clamp(y)
            s = views.score(y, np.flatnonzero(moved), base)
            if s > score:
                x, score = y, s
    return x, score


def _on_hull(model: BodyModel, params: np.ndarray, hull, n_headings: int) -> list:
    """``[("last", heading, params)]``: ``params`` moved horizontally onto the hull's centroid and
    turned about the vertical through it by ``n_headings`` evenly spaced angles (the first 0)."""
    moved = params.copy()
    shift = hull.centroid() - _centroid(model, params)
    shift[2] = 0.0
    moved[np.flatnonzero(model.param_kind == ROOT_TRANSLATION)] += shift
    pivot = _centroid(model, moved)
    return [("last", float(a), turn_about_vertical(model, moved, a, pivot))
            for a in 2 * np.pi * np.arange(n_headings) / n_headings]


def local_search(model: BodyModel, cameras: Sequence[Camera], chamfer: Sequence, views: ScoreViews, hull,
                 last: np.ndarray, *, n_headings: int = 12, accept_iou: float = 0.87, min_inside_fraction: float = 0.8,
                 max_iterations: int = 8, n_samples: int = 6, prior_rad: float = 50.0,
                 reverse_weight: float = 1.0, mirror_check: bool = True,
                 mirror_margin: float = 0.1) -> InitResult | None:
    """The cheap first stage of ``recover``: a local re-fit seeded from the last good pose.

    The last good pose as it was, and moved horizontally onto the centroid of ``hull`` and turned
    about the vertical to ``n_headings`` headings, is scored by IoU (``views``); the best gets a
    greedy limb search (``limb_search``) and one staged LM refinement (``tracker.search.initialise.refine``:
    root, joints, everything; ``n_samples`` contour points per side, the silhouette → model term
    at ``reverse_weight``).  With ``mirror_check`` the front/back mirror of the result
    (``tracker.search.mirror``) is refined the same way when its IoU is within ``mirror_margin`` of the
    result's (the silhouettes cannot tell them apart) and the lower ``front_back_cost`` is kept.

    Returns an ``InitResult`` (label ``"local/kept"`` or ``"local/mirrored"``) when its mean IoU
    is at least ``accept_iou`` and its inside fraction at least ``min_inside_fraction``, else
    None (the caller then runs the full search).
    """
    from tracker.search.mirror import _at_limits, _heading, front_back_cost, mirror_params

    turned = [p for _, _, p in _on_hull(model, last, hull, n_headings)]
    starts = [(views.score(p), p) for p in [last] + turned]
    score, start = max(starts, key=lambda sp: sp[0])
    start, _ = limb_search(model, views, start, score)
    x, terms = refine(model, cameras, chamfer, start, max_iterations=max_iterations, n_samples=n_samples,
                      prior_rad=prior_rad, reverse_weight=reverse_weight)
    iou = views.score(x)
    best = (front_back_cost(terms.rms_px(), iou, _at_limits(model, x)), "kept", x, terms, iou)
    if mirror_check:  # front or back: refined only where the mirror explains the silhouettes about as well
        m = model.clamp(mirror_params(model, x))
        if views.score(m) >= iou - mirror_margin:
            xm, terms_m = refine(model, cameras, chamfer, m, max_iterations=max_iterations, n_samples=n_samples,
                                 prior_rad=prior_rad, reverse_weight=reverse_weight)
            iou_m = views.score(xm)
            cost_m = front_back_cost(terms_m.rms_px(), iou_m, _at_limits(model, xm))
            if cost_m < best[0]:
                best = (cost_m, "mirrored", xm, terms_m, iou_m)
    _, label, x, terms, iou = best
    if not (iou >= accept_iou and terms.inside_fraction() >= min_inside_fraction):
        return None
    h = _heading(model, x)
    return InitResult(params=x, score=iou, rms_px=terms.rms_px(), inside_fraction=terms.inside_fraction(),
                      heading_rad=float(np.arctan2(h[1], h[0])), label=f"local/{label}",
                      height_m=estimate_height(hull, model), candidates=views.n_scored, hull=hull)


def recover(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
            chamfer: Mapping[str, object] | None, last_good_params, *, n_headings: int = 12, keep: int = 2,
            min_voxel_m: float = 0.03, score_scale: float = 0.5, max_iterations: int = 10, hull_tolerance: int = 0,
            prior_rad: float = 50.0, front_back: bool = True, local: bool = True,
            accept_iou: float = 0.87, iou_margin: float = 0.02) -> InitResult:
    """Re-initialise a lost track from the hull, seeded from ``last_good_params`` (n_params,).

    Parameters as in ``tracker.search.initialise.initialise``; the subject may be in any pose.
    ``local``: try the cheap ``local_search`` first, accepted at a mean silhouette IoU of
    ``accept_iou`` or of ``iou_margin`` below what a correct pose reaches on these views
    (``ScoreViews.expected_iou``: ~0.88 at 320x240, ~0.93 at 640x480), whichever is lower; a
    caller that knows what good frames reach on its segmentation (e.g. the tracker's recent IoU)
    can pass that less a few hundredths.  The full search runs only when the local stage fails.
    ``front_back``: finish with ``tracker.search.mirror.resolve_front_back`` (the winner against its
    mirror, both after a limb search and a full refinement).
    """
    cameras, sils, chs = prepare_inputs(model, cameras, silhouettes, chamfer)
    last = np.asarray(last_good_params, dtype=float)
    if last.shape != (model.n_params,) or not np.all(np.isfinite(last)):
        raise ValueError(f"last_good_params: expected a finite array of shape ({model.n_params},)")
    last = model.clamp(last)
    hull = visual_hull(cameras, sils, min_voxel_m=min_voxel_m, tolerance=hull_tolerance).largest_component()
    if hull.empty:
        raise ValueError("recover: the silhouettes share no volume (empty visual hull)")
    views = ScoreViews(model, cameras, sils, scale=score_scale)
    if local:
        accept = min(accept_iou, views.expected_iou() - iou_margin)  # lower views (320x240) score lower
        res = local_search(model, cameras, chs, views, hull, last, n_headings=n_headings, accept_iou=accept,
                           mirror_check=front_back)
        if res is not None:
            return res
    # 1. the last good pose moved onto the hull, at every heading
    cands = _on_hull(model, last, hull, n_headings) + pose_candidates(model, hull, n_headings=n_headings, hint=last)
    # 2. greedy limb search on the best hypotheses, 3. staged LM (weaker prior: any pose)
    res = refine_best(model, cameras, chs, views, hull, cands, keep=keep, max_iterations=max_iterations,
                      prepare=lambda p, s: limb_search(model, views, p, s), prior_rad=prior_rad, polish=True)
    if not front_back:
        return res
    # 4. front or back: the winner and its mirror, limb search and full refinement on both
    from tracker.search.mirror import resolve_front_back

    fb = resolve_front_back(model, cameras, silhouettes, chamfer, res.params, views=views,
                            prepared=(cameras, sils, chs), prepare=lambda p, s: limb_search(model, views, p, s))
    return replace(fb, label=f"{res.label}/{fb.label}", height_m=res.height_m, candidates=views.n_scored, hull=hull)
