"""Automatic initialisation from silhouettes: visual hull -> pose search -> staged LM refinement.

The subject stands in a T-pose or an A-pose anywhere in the capture volume, facing any direction
(BMVC'04 §4: a reference pose placed from the voxels' moments; IJCV'08 §6: root first, then the
limbs).  The steps, each in the module named:

1. **Hull** (``hull``) at a coarse resolution: position, floor, height, principal floor axes.
2. **Candidates** (``candidates.pose_candidates``): headings × arm poses, each arm on its own (a
   segmentation may lose one), scored by mean silhouette IoU (``scoring.ScoreViews``).
3. **Refinement** (``refine.refine_best``) of the best ``keep`` candidates; the best IoU wins.
4. **Front or back** (``mirror.resolve_front_back``): silhouettes hardly tell them apart, so the
   winner and its mirror both get a limb search and a full refinement and the lower
   chamfer + IoU + joint-limit cost is kept; the feet cue (``candidates.feet_direction``) counts
   only when the legs are straight (in a crouch the shanks lean forward and it points backwards).
5. **Elbows** (``refine.elbow_search``): a forearm bent in front of the trunk hides inside its
   outline, where the IoU cannot see it; bent-elbow hypotheses are kept when they lower the
   chamfer residual (internal edges included) + IoU cost.

Steps 3-5 are ``search_candidates``, shared with the any-pose search of
``tracker.search.recovery.recover``; ``SearchOptions`` configures both.  Measured effects of the
steps: docs/tuning.md, "Search".
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera
from tracker.body.model import BodyModel
from tracker.fitting.cost import ChamferCost
from tracker.fitting.sampler import ChamferViews, in_camera_order
from tracker.search.candidates import ARM_POSES_DEG, feet_direction, limb_search, pose_candidates
from tracker.search.hull import VoxelHull, visual_hull
from tracker.search.mirror import resolve_front_back
from tracker.search.refine import InitResult, elbow_search, refine_best
from tracker.search.scoring import ScoreViews, SearchInputs, prepare_inputs

__all__ = ["SearchOptions", "initialise", "search_views", "search_candidates"]


@dataclass(frozen=True)
class SearchOptions:
    """Options of a pose search from silhouettes (``initialise``; ``recover`` via ``for_recovery``).

    Each field's meaning and unit is commented where it is declared.

    Parameters
    ----------
    n_headings, arm_abduction_deg, keep
        The candidates and how many are refined.
    min_voxel_m, hull_tolerance, score_scale
        The visual hull and the IoU scoring views.
    max_iterations, prior_rad, search_limbs
        The candidates' refinement.
    use_feet, front_back, limb_search_both, elbows
        The front/back choice and the elbow search after it.
    local, accept_iou, iou_margin
        Recovery only: the cheap local stage.
    """

    #: evenly spaced headings searched (plus the two from the hull's major floor axis)
    n_headings: int = 12
    #: arm poses searched, degrees (0 = T, -45 = A), each arm on its own
    arm_abduction_deg: tuple[float, ...] = ARM_POSES_DEG
    #: candidates refined with LM (the best by IoU)
    keep: int = 3
    #: finest voxel size of the visual hull, metres
    min_voxel_m: float = 0.03
    #: views a hull point may fall outside of (``visual_hull``)
    hull_tolerance: int = 0
    #: image scale of the IoU scoring views
    score_scale: float = 0.5
    #: LM steps per refinement stage
    max_iterations: int = 10
    #: joint-angle prior of the candidates' refinement towards the candidate, px² per rad²
    #: (weaker for rougher hypotheses)
    prior_rad: float = 500.0
    #: limb-search each kept candidate before refining it, and the winner once more (any-pose search)
    search_limbs: bool = False
    #: the feet cue (``feet_direction``): with ``front_back`` a term of the front/back choice when the
    #: legs are straight; without, only the headings the feet point to are searched (unreliable in a
    #: crouch, where the shanks lean forward)
    use_feet: bool = True
    #: refine the winner and its mirror fully and keep the better (``resolve_front_back``): the
    #: candidate search alone picks the wrong one on a crouch or at low resolution
    front_back: bool = True
    #: limb-search the pose and its mirror before refining them
    limb_search_both: bool = True
    #: try bent elbows on the result (``elbow_search``)
    elbows: bool = True
    #: recovery only: try the cheap ``local_search`` first
    local: bool = True
    #: recovery only: mean IoU at which the local stage is accepted ...
    accept_iou: float = 0.87
    #: ... or this far below ``ScoreViews.expected_iou``, whichever is lower
    iou_margin: float = 0.02

    def __post_init__(self) -> None:
        for name in ("n_headings", "keep", "max_iterations"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name}: expected >= 1, got {getattr(self, name)!r}")
        for name in ("min_voxel_m", "score_scale"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name}: expected > 0, got {getattr(self, name)!r}")

    @classmethod
    def for_recovery(cls, **changes) -> "SearchOptions":
        """The any-pose search's defaults (``recover``), with ``changes`` applied.

        Two refined candidates, a weaker prior, limb searches on them, no feet cue, no elbow search.

        Parameters
        ----------
        **changes
            Field values to override.

        Returns
        -------
        SearchOptions
        """
        return replace(cls(keep=2, prior_rad=50.0, search_limbs=True, use_feet=False, elbows=False), **changes)


def search_views(model: BodyModel, inputs: SearchInputs, options: SearchOptions, *,
                 caller: str) -> tuple[VoxelHull, ScoreViews]:
    """The visual hull (largest component) and the IoU scoring views of a frame set.

    Parameters
    ----------
    model : BodyModel
    inputs : SearchInputs
    options : SearchOptions
    caller : str
        Named in the error.

    Returns
    -------
    hull : VoxelHull
    views : ScoreViews

    Raises
    ------
    ValueError
        The silhouettes share no volume.
    """
    hull = visual_hull(inputs.cameras, inputs.silhouettes, min_voxel_m=options.min_voxel_m,
                       tolerance=options.hull_tolerance).largest_component()
    if hull.empty:
        raise ValueError(f"{caller}: the silhouettes share no volume (empty visual hull)")
    return hull, ScoreViews(model, inputs.cameras, inputs.silhouettes, scale=options.score_scale)


def search_candidates(model: BodyModel, inputs: SearchInputs, hull: VoxelHull, views: ScoreViews,
                      candidates: Sequence[tuple[str, float, np.ndarray]], options: SearchOptions, *,
                      facing: np.ndarray | None = None) -> InitResult:
    """Refine the best candidates, then front/back and elbows (the steps ``initialise`` and ``recover`` share).

    Parameters
    ----------
    model : BodyModel
    inputs : SearchInputs
    hull : VoxelHull
    views : ScoreViews
    candidates : sequence of (label, heading_rad, params)
        As ``pose_candidates`` gives them.
    options : SearchOptions
    facing : ndarray, shape (2,), optional
        The feet cue for the front/back choice (``feet_direction``).

    Returns
    -------
    InitResult
        Label ``"<candidate>[+elbows]/<kept|mirrored>"`` (just the candidate without ``front_back``).
    """
    def limbs(p, s):
        return limb_search(model, views, p, s)

    best = refine_best(model, inputs.cameras, inputs.chamfer, views, hull, candidates, keep=options.keep,
                       max_iterations=options.max_iterations, prior_rad=options.prior_rad,
                       prepare=limbs if options.search_limbs else None, polish=options.search_limbs)
    if not options.front_back:
        return best
    res = resolve_front_back(model, inputs.cameras, None, None, best.params, views=views, prepared=inputs,
                             feet_direction=facing, prepare=limbs if options.limb_search_both else None)
    if options.elbows:
        x, _ = elbow_search(model, inputs.cameras, inputs.chamfer, views, res.params)
        if not np.array_equal(x, res.params):
            terms = ChamferCost(model, inputs.cameras, in_camera_order(inputs.chamfer, inputs.cameras),
                                n_samples=8).evaluate(x)
            res = replace(res, params=x, score=views.score(x), rms_px=terms.rms_px(),
                          inside_fraction=terms.inside_fraction())
            best = replace(best, label=f"{best.label}+elbows")
    return replace(res, label=f"{best.label}/{res.label}", height_m=best.height_m,
                   candidates=views.n_scored, hull=hull)


def initialise(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
               chamfer: ChamferViews | None = None, *, options: SearchOptions = SearchOptions()) -> InitResult:
    """Find the pose of a person standing in a T- or A-pose from silhouettes alone.

    With a previous pose use ``tracker.search.recovery.recover`` (any pose).

    Parameters
    ----------
    model : BodyModel
        Sized (``tracker.search.candidates.sized_model`` or ``InitResult.height_m`` size it).
    cameras : sequence of Camera
    silhouettes : mapping str -> ndarray, shape (h, w)
        Camera name -> mask, non-zero = body.
    chamfer : mapping str -> ChamferSampler, optional
        Camera name -> sampler (``tracker.fitting.sampler``); default: built from the
        silhouettes (outline as edges).
    options : SearchOptions

    Returns
    -------
    InitResult

    Raises
    ------
    ValueError
        Bad views (the camera named) or no common volume.
    """
    inputs = prepare_inputs(model, cameras, silhouettes, chamfer)
    hull, views = search_views(model, inputs, options, caller="initialise")
    facing = feet_direction(hull) if options.use_feet else None
    cands = pose_candidates(model, hull, n_headings=options.n_headings, arm_abduction_deg=options.arm_abduction_deg,
                            facing=None if options.front_back else facing)
    return search_candidates(model, inputs, hull, views, cands, options, facing=facing)
