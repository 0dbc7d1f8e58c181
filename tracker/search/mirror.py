"""Front/back ambiguity: the mirrored body and the choice between a pose and its mirror.

Silhouettes hardly tell a person's front from their back: a body and the same body reflected
in its frontal plane (the vertical plane through the pelvis holding the left–right axis) cast
nearly the same outlines, more so at low resolution where the feet and the nose are a few
pixels.  The reflected body is a real body once left and right are swapped: it is the pose
turned 180° about the vertical through the pelvis with the left and right chains exchanged
(``mirror_params``).  Which of the two is right shows in what does not mirror:

* joint limits — knees bend backwards only, elbows forwards: a mirrored fit of a crouch or a
  lean has to contort (joints at their limits, limbs and trunk off the outline);
* the internal edges (the outlines of limbs inside the silhouette), part of the chamfer cost;
* the feet, which reach forward of the ankles (``tracker.search.candidates.feet_direction``), when
  the hull shows them clearly.

``resolve_front_back`` refines a pose and its mirror fully (root, joints, everything: staged LM
of ``tracker.search.refine.refine``) and keeps the one with the lower ``front_back_cost``;
``compare_front_back`` gives every hypothesis's figures.

Mirror algebra (the models mirror the right side's DOF axes: ``-x``/``-z`` where the left
side has ``x``/``z``).  With S = diag(1, -1, 1) the reflection of a part frame in the body's
sagittal plane, S Rot(a, λ) S = Rot(-S a, λ): a DOF of axis a maps to the DOF of the other side
(or itself, on the trunk) whose axis is ±(-S a), with its value times that sign; the root
rotation R becomes Rz(π) R and the pelvis stays in place.  For an upright body the result is
the reflection of the original in its frontal plane; ``mirror_params`` is an involution.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera, matrix_to_rodrigues
from tracker.body.kinematics import so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.fitting.sampler import ChamferViews
from tracker.search.refine import InitResult, Prepare, refine
from tracker.search.scoring import ScoreViews, SearchInputs, prepare_inputs

__all__ = ["mirror_map", "exchange_sides", "mirror_params", "mirror_joint_order", "joints_at_limits", "pelvis_heading",
           "front_back_cost", "hypothesis_cost", "FrontBack", "compare_front_back", "resolve_front_back"]

_S = np.diag([1.0, -1.0, 1.0])
_RZ_PI = np.diag([-1.0, -1.0, 1.0])


def _other_side(name: str) -> str:
    for a, b in (("left_", "right_"), ("right_", "left_")):
        if name.startswith(a):
            return b + name[len(a):]
    return name


@lru_cache(maxsize=16)
def _mirror_map_cached(model: BodyModel) -> tuple[np.ndarray, np.ndarray]:
    n = model.n_params
    index, sign = np.arange(n), np.ones(n)
    for k in np.flatnonzero(model.param_kind == JOINT_ROTATION):
        other = _other_side(model.param_names[k])
        if other not in model.param_names:
            raise ValueError(f"model {model.name!r}: DOF {model.param_names[k]!r} has no mirror {other!r}")
        j = model.param_names.index(other)
        want = -_S @ model.param_axis[k]
        s = float(model.param_axis[j] @ want)
        if not np.isclose(abs(s), 1.0, atol=1e-9):
            raise ValueError(f"model {model.name!r}: DOF {model.param_names[j]!r} axis {model.param_axis[j]} "
                             f"does not mirror {model.param_names[k]!r} axis {model.param_axis[k]}")
        index[k], sign[k] = j, np.sign(s)
    index.setflags(write=False)
    sign.setflags(write=False)
    return index, sign


def mirror_map(model: BodyModel) -> tuple[np.ndarray, np.ndarray]:
    """Joint-parameter permutation and signs of the left/right reflection.

    ``mirrored[index[k]] = sign[k] * params[k]`` for every joint DOF k (root entries: identity).

    Parameters
    ----------
    model : BodyModel

    Returns
    -------
    index : ndarray of int, shape (n_params,)
    sign : ndarray, shape (n_params,)

    Raises
    ------
    ValueError
        A DOF whose mirror is missing or whose axis does not mirror (named).
    """
    return _mirror_map_cached(model)


def mirror_joint_order(model: BodyModel) -> np.ndarray:
    """Permutation of ``model.joint_names`` swapping ``left_*`` and ``right_*``, shape (n_joints,)."""
    names = list(model.joint_names)
    return np.array([names.index(_other_side(n)) if _other_side(n) in names else i for i, n in enumerate(names)])


def exchange_sides(model: BodyModel, params: np.ndarray, dofs: np.ndarray) -> np.ndarray:
    """``params`` (n_params,) with the joint angles ``dofs`` (indices; left and right chains together)
    moved to their other-side twins with the signs of ``mirror_map``; every other parameter unchanged."""
    p = np.asarray(params, dtype=float)
    if p.shape != (model.n_params,):
        raise ValueError(f"params: expected shape ({model.n_params},), got {p.shape}")
    index, sign = mirror_map(model)
    out = p.copy()
    out[index[dofs]] = sign[dofs] * p[dofs]
    return out


def mirror_params(model: BodyModel, params: np.ndarray) -> np.ndarray:
    """The same body turned 180° about the vertical through the pelvis, left and right swapped.

    The pelvis origin stays where it is; the root rotation R becomes Rz(π) R; left and right joint
    angles are exchanged (signs from the models' mirrored axes, ``mirror_map``).  Applying it twice
    gives ``params`` back (the root rotation vector up to its 2π equivalents).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)

    Returns
    -------
    ndarray, shape (n_params,)
    """
    p = np.asarray(params, dtype=float)
    out = exchange_sides(model, p, np.flatnonzero(model.param_kind == JOINT_ROTATION))
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    r_idx = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    root = int(np.flatnonzero(model.parent < 0)[0])
    R = so3_exp(p[r_idx])
    R2 = _RZ_PI @ R
    pelvis = p[t_idx] + R @ model.offset[root]
    out[t_idx] = pelvis - R2 @ model.offset[root]
    out[r_idx] = matrix_to_rodrigues(R2)
    return out


# ----------------------------------------------------------------------------- choosing
def joints_at_limits(model: BodyModel, params: np.ndarray, *, tol_rad: float = np.radians(1.0)) -> int:
    """Joint DOF within ``tol_rad`` of a limit.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    tol_rad : float
        Radians.

    Returns
    -------
    int
    """
    j = model.param_kind == JOINT_ROTATION
    return int(np.count_nonzero(np.minimum(params - model.lower, model.upper - params)[j] < tol_rad))


def pelvis_heading(model: BodyModel, params: np.ndarray) -> np.ndarray:
    """Horizontal unit vector the pelvis faces (its +x axis).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)

    Returns
    -------
    ndarray, shape (2,)
        Zeros when the axis points up or down.
    """
    R = so3_exp(params[model.param_kind == ROOT_ROTATION])
    root = int(np.flatnonzero(model.parent < 0)[0])
    x = (R @ model.rest_rotation[root])[:2, 0]
    n = float(np.linalg.norm(x))
    return x / n if n > 1e-6 else np.zeros(2)


def _straight_legs(model: BodyModel, params: np.ndarray, *, max_rad: float = np.radians(20.0)) -> bool:
    """Knees and hips within ``max_rad`` of straight: the feet cue is trustworthy (upright stance)."""
    names = [n for n in model.param_names if n.split(".")[0].endswith(("_shank", "_thigh")) and n.endswith(".flexion")]
    return bool(np.all(np.abs(params[[model.param_names.index(n) for n in names]]) < max_rad))


def front_back_cost(rms_px: float, iou: float, at_limits: int, feet: float = 0.0, *, iou_weight: float = 10.0,
                    limit_weight: float = 0.1) -> float:
    """Cost of a refined hypothesis (lower is better).

    Parameters
    ----------
    rms_px : float
        RMS chamfer residual, pixels (the silhouette and the internal-edge terms).
    iou : float
        Mean silhouette IoU.
    at_limits : int
        Joint DOF pinned at a limit (a mirrored crouch contorts).
    feet : float
        The feet-cue term (0: none).
    iou_weight : float
        Weight of 1 - IoU.
    limit_weight : float
        Cost per DOF at a limit.

    Returns
    -------
    float
        ``rms_px + iou_weight (1 - iou) + limit_weight at_limits + feet``.
    """
    return float(rms_px + iou_weight * (1.0 - iou) + limit_weight * at_limits + feet)


def hypothesis_cost(model: BodyModel, params, rms_px: float, iou: float) -> float:
    """``front_back_cost`` of a fitted pose, its joint-limit count from ``params``, no feet cue.

    What the tracker's periodic front/back check (``tracker.fitting.tracking.Tracker``) compares a
    pose and its mirror by.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    rms_px : float
        RMS chamfer residual at ``params``, pixels.
    iou : float
        Mean silhouette IoU at ``params``.

    Returns
    -------
    float
    """
    return front_back_cost(rms_px, iou, joints_at_limits(model, np.asarray(params, dtype=float)))


@dataclass(frozen=True, eq=False)
class FrontBack:
    """Every refined hypothesis of ``compare_front_back``.

    k = 2 (the pose, its mirror) or up to 4 (each also after the ``prepare`` search, where that
    changed it).

    Attributes
    ----------
    params : ndarray, shape (k, n_params)
        Refined poses.
    mirrored : ndarray of bool, shape (k,)
        Started from the mirror.
    cost : ndarray, shape (k,)
        ``front_back_cost`` (inf where not finite).
    rms_px : ndarray, shape (k,)
        RMS chamfer residual, pixels (silhouette and internal edges).
    iou : ndarray, shape (k,)
        Mean silhouette IoU.
    at_limits : ndarray of int, shape (k,)
        Joint DOF within 1° of a limit.
    feet : ndarray, shape (k,)
        Feet-cue term (0 when the cue is unclear).
    inside_fraction : ndarray, shape (k,)
        Fraction of contour points on the silhouettes.
    best : int
        Index of the lowest cost.
    """

    params: np.ndarray
    mirrored: np.ndarray
    cost: np.ndarray
    rms_px: np.ndarray
    iou: np.ndarray
    at_limits: np.ndarray
    feet: np.ndarray
    inside_fraction: np.ndarray
    best: int

    def choice(self, model: BodyModel) -> InitResult:
        """The lowest-cost hypothesis as an ``InitResult`` (label ``"kept"`` or ``"mirrored"``).

        Parameters
        ----------
        model : BodyModel
            The model the hypotheses were fitted with (its height is recorded).

        Returns
        -------
        InitResult
        """
        b = self.best
        h = pelvis_heading(model, self.params[b])
        other = np.flatnonzero(self.mirrored != self.mirrored[b])
        mirror = self.params[other[np.argmin(self.cost[other])]] if other.size else None
        return InitResult(params=self.params[b], mirror=mirror, score=float(self.iou[b]), rms_px=float(self.rms_px[b]),
                          inside_fraction=float(self.inside_fraction[b]), heading_rad=float(np.arctan2(h[1], h[0])),
                          label=("kept", "mirrored")[int(self.mirrored[b])], height_m=float(model.height_m),
                          candidates=len(self.params))


def compare_front_back(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
                       chamfer: ChamferViews | None, params, *, max_iterations: int = 15,
                       prior_rad: float = 30.0, reverse_weight: float = 1.0, feet_direction=None,
                       feet_weight: float = 0.5, views: ScoreViews | None = None,
                       prepared: SearchInputs | None = None, prepare: Prepare | None = None) -> FrontBack:
    """Refine a pose and its mirror fully (staged LM of ``refine``) and score them by ``front_back_cost``.

    Parameters
    ----------
    model, cameras
    silhouettes : mapping str -> ndarray, shape (h, w)
        Camera name -> mask, non-zero = body.
    chamfer : mapping str -> ChamferSampler, or None
        Camera name -> sampler; None: built from the silhouettes.
    params : ndarray, shape (n_params,)
        The pose; must be finite.
    max_iterations, prior_rad, reverse_weight : int, float, float
        ``refine``: LM steps per stage, weak joint-angle prior towards each start (px² per rad²),
        weight of the silhouette -> model term.
    feet_direction : ndarray, shape (2,), optional
        ``feet_direction`` of the hull: adds ``feet_weight`` × (1 - cos) between the pelvis heading
        and it, only when every refined pose has straight legs (in a crouch the cue turns round).
    feet_weight : float
    views, prepared : ScoreViews, SearchInputs, optional
        Scoring views and ``prepare_inputs`` of these views, to reuse.
    prepare : callable, optional
        ``prepare(params, iou) -> (params, iou)``, e.g. ``limb_search``: its result on each start is
        refined and compared as well (the mirror's limbs may sit better elsewhere).

    Returns
    -------
    FrontBack
    """
    inputs = prepare_inputs(model, cameras, silhouettes, chamfer) if prepared is None else prepared
    p = np.asarray(params, dtype=float)
    if p.shape != (model.n_params,) or not np.all(np.isfinite(p)):
        raise ValueError(f"params: expected a finite array of shape ({model.n_params},)")
    if views is None:
        views = ScoreViews(model, inputs.cameras, inputs.silhouettes, scale=0.5)
    starts, mirrored = [], []
    for flag, start in ((False, model.clamp(p)), (True, model.clamp(mirror_params(model, p)))):
        starts.append(start)
        mirrored.append(flag)
        if prepare is not None:  # the limb search's start too, unless it changed nothing
            searched, _ = prepare(start, views.score(start))
            if not np.array_equal(searched, start):
                starts.append(searched)
                mirrored.append(flag)
    outs, terms_list = [], []
    for start in starts:
        x, terms = refine(model, inputs.cameras, inputs.chamfer, start, max_iterations=max_iterations,
                          prior_rad=prior_rad, reverse_weight=reverse_weight, ftol=1e-4, n_samples=8)
        outs.append(x)
        terms_list.append(terms)
    rms = np.array([t.rms_px() for t in terms_list])
    iou = views.scores(outs)
    lim = np.array([joints_at_limits(model, x) for x in outs])
    feet = np.zeros(len(outs))
    if feet_direction is not None and all(_straight_legs(model, x) for x in outs):
        f = np.asarray(feet_direction, dtype=float)
        feet = np.array([feet_weight * (1.0 - float(pelvis_heading(model, x) @ f)) for x in outs])
    cost = np.array([front_back_cost(r, i, l, fe) for r, i, l, fe in zip(rms, iou, lim, feet)])
    cost = np.where(np.isfinite(cost), cost, np.inf)
    return FrontBack(params=np.array(outs), mirrored=np.array(mirrored), cost=cost, rms_px=rms, iou=iou,
                     at_limits=lim, feet=feet, inside_fraction=np.array([t.inside_fraction() for t in terms_list]),
                     best=int(np.argmin(cost)))


def resolve_front_back(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
                       chamfer: ChamferViews | None, params, **options) -> InitResult:
    """Refine ``params`` and ``mirror_params(params)`` fully and keep the better one.

    Parameters
    ----------
    model, cameras, silhouettes, chamfer, params
        As ``compare_front_back``.
    **options
        Keyword options of ``compare_front_back``.

    Returns
    -------
    InitResult
        Label ``"kept"`` or ``"mirrored"``; ``compare_front_back`` gives every hypothesis.
    """
    return compare_front_back(model, cameras, silhouettes, chamfer, params, **options).choice(model)
