"""The subject's body (segment lengths, widths, radii) from fitted poses and silhouettes (subject calibration).

Given a few frame sets with a pose already fitted (by the tracker, on a model of default
proportions) and each camera's silhouette, :func:`estimate_segment_lengths` alternates

1. each frame's pose polished by coordinate ascent of the silhouette IoU
   (``tracker.search.seated.polish_iou`` over every parameter) on the current model;
2. each segment's length (the model file's ``segment`` names; left and right share one), then
   each requested width (``hip_width``, ``shoulder_width``: the distance between the two joint
   centres) and radius group's factor (both cone axes of ``thigh``, ...; ``trunk_width`` and
   ``trunk_depth`` one axis of the trunk's cones each) set to the value maximising the IoU summed over the frames (each frame's root translation re-polished for every candidate:
   a longer trunk or leg moves the whole body), searched on a grid of scale factors around the
   current value and refined by a parabola through the best grid point and its neighbours; each
   candidate is scored under a prior that keeps it near the anthropometric ratio of the model
   (a Gaussian on the log scale factor: ``prior_sigma`` for lengths, ``width_sigma`` and
   ``radius_sigma`` for the others).

Segments are searched from the trunk outwards (a thigh's length moves the shank's silhouette, not
the reverse).  The silhouettes should hold the body only (clutter cut, ``tracker.fitting.scene``):
the IoU counts a prop the body does not cover, and a limb lengthened onto it would score.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from capture.tomlio import load_file
from tracker.body.kinematics import forward
from tracker.body.model import MODELS_DIR, BodyModel, load_model
from tracker.search.scoring import ScoreViews
from tracker.search.seated import polish_iou

__all__ = ["SubjectFit", "pose_steps", "nominal_segment_lengths", "nominal_widths", "estimate_segment_lengths", "SEGMENT_ORDER",
           "SCORE_INSET_PX",
           "WIDTH_ORDER", "RADIUS_ORDER"]

#: Search order, trunk first.
SEGMENT_ORDER = ("abdomen", "torso", "thigh", "upper_arm", "shank", "forearm")
#: Widths and radius groups, searched after the lengths in this order.
WIDTH_ORDER = ("hip_width", "shoulder_width")
RADIUS_ORDER = ("trunk_width", "trunk_depth", "thigh", "upper_arm", "shank", "forearm")
#: The ``ScoreViews.inset_px`` at which the model is drawn as large as the observed silhouettes of the same
#: body are at scale 0.5 (the outline's half-pixel growth taken off, less the growth of a mask halved by
#: area averaging with ties kept): no other body scores better on the model's own renders.  Not the
#: calibration's default (``inset_px=0``, the tracker's own views): docs/subject_calibration.md, round 15.
SCORE_INSET_PX = 0.35


@dataclass(frozen=True)
class SubjectFit:
    """Result of :func:`estimate_segment_lengths`.

    Attributes
    ----------
    segment_lengths : dict str -> float, metres
    model : BodyModel sized with them (and the widths and radii)
    params : list of ndarray, shape (n_params,), the polished pose per frame
    iou_before, iou_after : float, mean silhouette IoU over frames and cameras at the start and end
    widths : dict str -> float, metres (those fitted)
    radius_scale : dict str -> float, factors on the model's radii (those fitted)
    """

    segment_lengths: dict
    model: BodyModel
    params: list
    iou_before: float
    iou_after: float
    widths: dict = field(default_factory=dict)
    radius_scale: dict = field(default_factory=dict)


def nominal_segment_lengths(model: BodyModel) -> dict[str, float]:
    """Segment name -> the model file's anthropometric length at ``model.height_m`` (metres)."""
    path = MODELS_DIR / f"{model.name}.toml"
    data = load_file(path, what="model file")
    out = {}
    for part in data.get("part", []):
        seg = part.get("segment")
        if seg is not None and seg not in out:
            out[str(seg)] = float(part.get("length", part["cone"]["z2"])) * model.height_m
    return out


def nominal_widths(model: BodyModel) -> dict[str, float]:
    """Width name -> the distance (metres) between the origins of its two parts at the reference pose
    of the model sized by ``model.height_m`` alone."""
    plain = load_model(model.name, height_m=model.height_m)
    pose = forward(plain, plain.zero())
    return {name: float(abs(pose.translation[parts[0], 1] - pose.translation[parts[-1], 1]))
            for name, parts in plain.width_parts.items()}


def pose_steps(model: BodyModel, factor: float) -> dict[str, float]:
    """Parameter name -> ``polish_iou`` step: ``factor`` × 0.03 m (root translation), 0.08 rad (root
    rotation), 0.12 rad (joints)."""
    steps = {}
    for name, kind in zip(model.param_names, model.param_kind):
        steps[name] = factor * (0.03 if kind == 0 else (0.08 if kind == 1 else 0.12))
    return steps


def estimate_segment_lengths(model: BodyModel, cameras: Sequence[Camera], poses: Sequence[np.ndarray],
                             silhouettes: Sequence[Mapping[str, np.ndarray]], *, rounds: int = 3,
                             span: float = 0.25, step: float = 0.025, prior_sigma: float = 0.3,
                             polish_rounds: int = 4, pose_step: float = 0.5, root_rounds: int = 2, scale: float = 0.5,
                             segments: Sequence[str] = SEGMENT_ORDER, widths: Sequence[str] = (),
                             radii: Sequence[str] = (), width_sigma: float = 0.2,
                             radius_sigma: float = 0.2, inset_px: float = 0.0) -> SubjectFit:
    """Fit segment lengths (and optionally widths and radii) to silhouettes, jointly with the frames' poses.

    Parameters
    ----------
    model : BodyModel
        The model the poses were fitted with (its height sets the anthropometric prior).
    cameras : sequence of Camera; poses : sequence of ndarray, each shape (n_params,), one per frame set
    silhouettes : sequence of mapping camera name -> ndarray (h, w)
        Per frame set, each camera's body silhouette (non-zero = body).
    rounds, polish_rounds : int
        Pose-polish / size-search alternations (later ones search half the span); ``polish_iou``
        rounds per frame in each.
    span, step : float
        Scale factors searched: current × (1 ± span) in steps of ``step`` (first round).
    prior_sigma, width_sigma, radius_sigma : float
        Standard deviation of the log scale factor against the anthropometric length, width, radius.
    pose_step : float
        Factor on ``polish_iou``'s first steps (0.03 m root, 0.08 rad root rotation, 0.12 rad joints).
    root_rounds : int
        ``polish_iou`` rounds of the root translation (1 cm steps) for every candidate (0: none).
    scale, inset_px : float
        Image scale and ``ScoreViews.inset_px`` of the scoring views (``SCORE_INSET_PX``: unbiased).
    segments, widths, radii : sequence of str
        Segments, widths (``WIDTH_ORDER``) and radius groups (``RADIUS_ORDER``) to fit (those the model has).

    Returns
    -------
    SubjectFit
    """
    if len(poses) != len(silhouettes) or not poses:
        raise ValueError("estimate_segment_lengths: need one silhouette set per pose, at least one")
    names = [c.name for c in cameras]
    views = [ScoreViews(model, cameras, [np.asarray(s[n]) for n in names], scale=scale, inset_px=inset_px)
             for s in silhouettes]
    nominal = {("length", k): v for k, v in nominal_segment_lengths(model).items()}
    nominal.update({("width", k): v for k, v in nominal_widths(model).items()})
    nominal.update({("radius", k): 1.0 for k in model.radius_groups})
    sigma = {"length": prior_sigma, "width": width_sigma, "radius": radius_sigma}
    dims = [("length", s) for s in segments if s in model.segments] + [("width", w) for w in widths]
    dims += [("radius", r) for r in radii]
    dims = [d for d in dims if d in nominal]
    values = {d: nominal[d] for d in dims}

    def by_kind(vals) -> dict[str, dict[str, float]]:
        return {kind: {n: v for (k, n), v in vals.items() if k == kind} for kind in sigma}

    def build(vals) -> BodyModel:
        parts = by_kind(vals)
        return load_model(model.name, height_m=model.height_m, segment_lengths=parts["length"],
                          widths=parts["width"], radius_scale=parts["radius"])

    params = [model.clamp(np.asarray(p, dtype=float)) for p in poses]
    current = model
    iou_before = float(np.mean([v.score(p) for v, p in zip(views, params)]))
    steps = pose_steps(model, pose_step)

    root = {n: 0.01 for n, k in zip(model.param_names, model.param_kind) if k == 0}
    # a width moves a joint sideways: the joints below it re-polished too (else their angles, polished
    # for the old width, hold it: the limb swings to keep its silhouette)
    width_steps = {w: {**root, **{model.param_names[k]: 0.03 for k in np.flatnonzero(np.isin(model.param_part, parts))}}
                   for w, parts in model.width_parts.items()}

    def total(m: BodyModel, dim) -> float:
        if not root_rounds:
            return float(sum(v.with_model(m).score(p) for v, p in zip(views, params)))
        st = width_steps[dim[1]] if dim[0] == "width" else root
        return float(sum(polish_iou(m, v.with_model(m), p, steps=st, rounds=root_rounds)[1]
                         for v, p in zip(views, params)))

    for r in range(int(rounds)):
        params = [polish_iou(current, v.with_model(current), p, steps=steps, rounds=polish_rounds)[0]
                  for v, p in zip(views, params)]
        half = span / (2 ** r)
        grid = np.arange(-half, half + 1e-9, step / (2 ** r))
        for dim in dims:
            cands = values[dim] * (1.0 + grid)
            ok = (cands > 0.5 * nominal[dim]) & (cands < 1.8 * nominal[dim])
            cands = cands[ok]
            scores = np.array([total(build({**values, dim: c}), dim) for c in cands])
            # Gaussian prior on log(value / nominal), in units of the IoU summed over frames
            scores -= 0.5 * len(params) * 0.01 * (np.log(cands / nominal[dim]) / sigma[dim[0]]) ** 2
            i = int(np.argmax(scores))
            best = float(cands[i])
            if 0 < i < len(cands) - 1:
                y0, y1, y2 = scores[i - 1:i + 2]
                den = y0 - 2 * y1 + y2
                if den < 0:
                    best += 0.5 * (y0 - y2) / den * float(cands[i + 1] - cands[i])
            values[dim] = best
            current = build(values)
    iou_after = float(np.mean([v.with_model(current).score(p) for v, p in zip(views, params)]))
    fitted = by_kind(values)
    return SubjectFit(fitted["length"], current, params, iou_before, iou_after, fitted["width"], fitted["radius"])
