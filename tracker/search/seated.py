"""Initialisation of a subject who is not standing in a T- or A-pose: seated hypotheses.

``tracker.search.initialise.initialise`` searches a person standing in a T- or A-pose.  A
subject seated from the first frame (a studio take on a chair) fits none of those
hypotheses: the refinement then drapes the standing model over the chair.  ``seated_candidates``
places a seated posture (thighs forward, shanks down, arms hanging with the forearms on the
thighs) at every heading on the visual hull: its lowest point on the floor, its volume centred on
the hull's horizontally, then refined (root only) and lifted by ``polish_iou``.
``initialise_any`` runs both searches and keeps the pose with the best silhouette IoU
(``ScoreViews``: a limb missing from the model costs as much as one the images lack, so the
standing model folded over a chair scores below the seated one).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from tracker.body.kinematics import forward
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.fitting.cost import ChamferCost
from tracker.imaging.render import body_points
from tracker.search.hull import VoxelHull, visual_hull
from tracker.fitting.sampler import in_camera_order
from tracker.search.initialise import SearchOptions, initialise
from tracker.search.recovery import recover
from tracker.search.refine import InitResult, refine
from tracker.search.scoring import ScoreViews, prepare_inputs

__all__ = ["SEATED_DEG", "POLISH_STEPS", "seated_params", "seated_candidates", "polish_iou", "initialise_any"]

#: The seated posture, degrees per DOF name suffix (both sides): thighs forward, knees bent,
#: arms hanging with the forearms bent forward onto the thighs.
SEATED_DEG = {"thigh.flexion": 90.0, "shank.flexion": 90.0, "upper_arm.abduction": -80.0,
              "upper_arm.flexion": 15.0, "forearm.flexion": 60.0}


#: ``polish_iou``'s parameters and first steps (metres, radians): the root and the seated
#: posture's main joints, where a prop under the subject misleads the chamfer refinement.
POLISH_STEPS = {"pelvis.tx": 0.04, "pelvis.ty": 0.04, "pelvis.tz": 0.04, "pelvis.ry": 0.15, "pelvis.rz": 0.15,
                "abdomen.flexion": 0.15, "left_thigh.flexion": 0.15, "right_thigh.flexion": 0.15,
                "left_shank.flexion": 0.15, "right_shank.flexion": 0.15, "left_thigh.abduction": 0.1,
                "right_thigh.abduction": 0.1}


def polish_iou(model: BodyModel, views: ScoreViews, params: np.ndarray, *,
               steps: Mapping[str, float] = POLISH_STEPS, rounds: int = 6) -> tuple[np.ndarray, float]:
    """Coordinate ascent of the silhouette IoU (``views.score``) over the parameters of ``steps``:
    each is moved by ± its step and the move kept when the IoU rises; a round without a gain
    halves the steps.  ``rounds`` rounds (two scores per parameter each).  Returns ``(params, IoU)``.

    The chamfer refinement lets a body sink into a prop that is part of the silhouette (its
    contour lies inside the silhouette either way); the IoU counts the silhouette the body
    leaves uncovered and the body outside it, so it lifts the body back onto the person."""
    names = [n for n in steps if n in model.param_names]
    idx = np.array([model.param_names.index(n) for n in names], dtype=int)
    step = np.array([steps[n] for n in names], dtype=float)
    p = model.clamp(np.asarray(params, dtype=float))
    best = views.score(p)
    for _ in range(int(rounds)):
        gained = False
        for k, i in enumerate(idx):  # a few dozen parameters, not pixels
            for sign in (1.0, -1.0):
                q = p.copy()
                q[i] += sign * step[k]
                q = model.clamp(q)
                s = views.score(q)
                if s > best + 1e-4:
                    p, best, gained = q, s, True
        if not gained:
            step *= 0.5
    return p, float(best)


def seated_params(model: BodyModel, posture: Mapping[str, float] = SEATED_DEG) -> np.ndarray:
    """The posture (``{"thigh.flexion": deg, ...}``, both sides) at the origin, heading 0 (n_params,)."""
    p = model.zero()
    for suffix, deg in posture.items():
        for side in ("left", "right"):
            name = f"{side}_{suffix}"
            if name in model.param_names:
                p[model.param_names.index(name)] = np.radians(deg)
    return model.clamp(p)


def seated_candidates(model: BodyModel, hull: VoxelHull, *, n_headings: int = 12,
                      posture: Mapping[str, float] = SEATED_DEG) -> list:
    """``[(label, heading_rad, params)]``: the posture at ``n_headings`` evenly spaced headings,
    lowest point on the hull's floor, body centroid over the hull's centroid."""
    centroid = hull.centroid()
    floor = hull.extent()[0, 2]
    root_t = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    root_r = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    shape = seated_params(model, posture)
    out = []
    for psi in 2 * np.pi * np.arange(n_headings) / max(n_headings, 1):
        p = shape.copy()
        p[root_r] = [0.0, 0.0, (psi + np.pi) % (2 * np.pi) - np.pi]
        pts = body_points(model, forward(model, p), n_theta=8, n_z=2).reshape(-1, 3)
        p[root_t] += [centroid[0] - pts[:, 0].mean(), centroid[1] - pts[:, 1].mean(), floor - pts[:, 2].min()]
        out.append(("seated", float(p[root_r][2]), p))
    return out


def _seated_search(model: BodyModel, cams, sils, chs, hull: VoxelHull, *, n_headings: int, keep: int,
                   score_scale: float, max_iterations: int) -> tuple[float, np.ndarray, float, ScoreViews]:
    """Best seated pose on ``hull``: ``(IoU, params, heading, views)``."""
    views = ScoreViews(model, cams, sils, scale=score_scale)
    cands = seated_candidates(model, hull, n_headings=n_headings)
    scores = views.scores([p for _, _, p in cands])
    root = [np.flatnonzero(model.param_kind != JOINT_ROTATION)]
    best = None
    for i in np.argsort(-scores, kind="stable")[: max(1, int(keep))]:
        _, psi, p0 = cands[i]
        p, _ = refine(model, cams, chs, p0, stages=root, max_iterations=max_iterations)
        p, s = polish_iou(model, views, p)
        if best is None or s > best[0]:
            best = (s, p, psi, views)
    return best


def initialise_any(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
                   chamfer: Mapping[str, object] | None = None, *, hint=None, n_headings: int = 12,
                   keep: int = 3, min_voxel_m: float = 0.03, score_scale: float = 0.5,
                   max_iterations: int = 10, heights: Sequence[float] = ()) -> tuple[InitResult, BodyModel]:
    """The better (silhouette IoU) of ``initialise`` (standing T/A-pose, or recovery from ``hint``)
    and the seated search; arguments as ``initialise``.  ``heights`` (metres): the seated search
    is also run with ``model`` re-sized to each (a seated subject's height cannot be read off the
    hull).  Returns ``(result, the model it is a pose of)``."""
    search = SearchOptions(n_headings=n_headings, keep=keep, min_voxel_m=min_voxel_m, score_scale=score_scale,
                           max_iterations=max_iterations)
    if hint is None:
        standing = initialise(model, cameras, silhouettes, chamfer, options=search)
    else:
        standing = recover(model, cameras, silhouettes, chamfer, hint)
    inputs = prepare_inputs(model, cameras, silhouettes, chamfer)
    cams, sils, chs = inputs.cameras, inputs.silhouettes, inputs.chamfer
    hull = standing.hull if standing.hull is not None else visual_hull(cams, sils, min_voxel_m=min_voxel_m)
    hull = hull.largest_component()
    if hull.empty:
        return standing, model
    best, best_model, n_scored = None, model, 0
    for m in [model] + [model.with_height(h) for h in heights if abs(h - model.height_m) > 1e-6]:
        found = _seated_search(m, cams, sils, chs, hull, n_headings=n_headings, keep=keep,
                               score_scale=score_scale, max_iterations=max_iterations)
        n_scored += found[3].n_scored
        if best is None or found[0] > best[0]:
            best, best_model = found, m
    s, p, psi, views = best
    if s <= ScoreViews(model, cams, sils, scale=score_scale).score(np.asarray(standing.params)):
        return standing, model
    terms = ChamferCost(best_model, cams, in_camera_order(chs, cams), n_samples=8).evaluate(p)
    return InitResult(params=p, score=s, rms_px=terms.rms_px(), inside_fraction=terms.inside_fraction(),
                      heading_rad=psi, label="seated", height_m=best_model.height_m,
                      candidates=n_scored + standing.candidates, hull=hull), best_model
