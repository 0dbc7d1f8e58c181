"""Automatic initialisation from silhouettes: visual hull → pose search → staged LM refinement.

The subject stands in a T-pose or an A-pose anywhere in the capture volume, facing any
direction (BMVC'04 §4: a reference pose placed from the voxels' moments; IJCV'08 §6: root first,
then the limbs).

1. **Hull** (``tracker.search.hull``) at a coarse resolution: position (volume centroid, floor = the
   hull's lowest point), height, and the principal axes of its horizontal spread.
2. **Search** over heading × arm pose: ``n_headings`` evenly spaced headings plus the two
   headings that put the arms' span along the hull's major floor axis, each arm at every
   abduction of ``arm_abduction_deg`` (0° = T, -45° = A; the arms independently, as a
   segmentation may lose one).  Candidates are scored by the mean silhouette IoU
   of the model (``ScoreViews``: the parts' projected convex hulls on half-size views), a
   symmetric score: a limb missing from the model costs as much as a limb the images lack.
3. **Refinement** of the best ``keep`` candidates with bounded robust LM on the chamfer cost
   (``tracker.fitting.cost`` / ``tracker.fitting.solver``): root only, then the joints, then everything.  The
   refined candidate with the best IoU wins (the chamfer cost is model→image only, so it cannot
   tell a model whose limb hides inside the body from the right one).
4. **Front or back** (``tracker.search.mirror.resolve_front_back``): silhouettes hardly tell them
   apart, so the winner and its mirror (turned 180°, left and right swapped) both get a limb
   search (``tracker.search.recovery.limb_search``) and a full refinement, and the one with the lower
   chamfer + IoU + joint-limit cost is kept; the feet cue (``feet_direction``: the hull's sole
   layer lies ahead of its shanks) counts only when the legs are straight — in a crouch the
   shanks lean forward and it points backwards (it used to drop the headings it disagreed
   with, which turned the demo's hop round).
5. **Elbows** (``elbow_search``): a forearm bent in front of the trunk hides inside the trunk's
   outline, where the IoU cannot see it; for each arm, bent-elbow hypotheses are refined fully
   and kept when they lower chamfer residual (internal edges included) + IoU cost (hop clip, 4
   cameras 640x480, tracked 30 frames from automatic initialisation: 28 -> 14.5 mm).

With a ``hint`` (a previous pose) the any-pose search of ``tracker.search.recovery.recover`` runs instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

import cv2
import numpy as np

from capture.camera import Camera
from tracker.fitting.cost import ChamferCost
from tracker.search.hull import VoxelHull, visual_hull
from tracker.body.kinematics import forward
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.imaging.render import body_points, cone_points
from tracker.fitting.solver import levenberg_marquardt

__all__ = ["InitResult", "initialise", "refine", "refine_best", "prepare_inputs", "ScoreViews", "pose_candidates",
           "feet_direction", "chamfer_from_silhouette", "rendered_views", "model_top_m", "estimate_height",
           "sized_model", "ARM_POSES_DEG", "elbow_search", "ELBOW_SEARCH_DEG"]

#: Arm abductions tried by default (degrees; 0 = T-pose, negative lowers the arms).
ARM_POSES_DEG = (0.0, -45.0)


@dataclass(frozen=True, eq=False)
class InitResult:
    """Outcome of an initialisation.

    params : (n_params,) the pose; score : mean silhouette IoU of that pose (1 = perfect);
    rms_px : RMS chamfer residual at ``params`` (NaN if no refinement ran);
    inside_fraction : fraction of contour points on the silhouettes; heading_rad : the search
    heading it came from; label : which hypothesis won (``"T"``, ``"A"``, ``"T/A"`` = left T,
    right A, ``"hint"``, ``"last"``, ``"local"``; ``"+elbows"`` when ``elbow_search`` changed
    the pose), followed by ``"/kept"`` or ``"/mirrored"`` after the front/back check
    (``tracker.search.mirror.resolve_front_back``);
    height_m : the subject height the hull suggests; candidates : poses scored;
    hull : the visual hull used.  ``np.asarray(result)`` gives ``params``.
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

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self.params, dtype=dtype)


# ----------------------------------------------------------------------------- scoring
class ScoreViews:
    """Silhouettes and cameras down-scaled by ``scale`` for fast overlap scoring of poses.

    Parameters
    ----------
    model : BodyModel; cameras : sequence of Camera; silhouettes : sequence of (h, w) masks
    (non-zero = body), one per camera; scale : image scale of the scoring views
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], silhouettes: Sequence[np.ndarray], *,
                 scale: float = 0.5) -> None:
        self.model = model
        self.cameras, self.masks = [], []
        for cam, sil in zip(cameras, silhouettes):
            w, h = max(1, int(round(cam.width * scale))), max(1, int(round(cam.height * scale)))
            sx, sy = w / cam.width, h / cam.height
            # pixel centres at integers: u' = sx (u + 0.5) - 0.5
            S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
            self.cameras.append(Camera(cam.name, S @ cam.matrix, cam.distortion, cam.rotation, cam.translation, (w, h)))
            small = cv2.resize((np.asarray(sil) > 0).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
            self.masks.append(small >= 0.5)
        self._local = cone_points(model, n_theta=12, n_z=2)  # (n_parts, 24, 3) part frames
        self.n_scored = 0

    def render(self, params: np.ndarray, parts: np.ndarray | None = None,
               base: Sequence[np.ndarray] | None = None) -> list[np.ndarray]:
        """The model's silhouette in each scoring view, (h', w') bool: the union of the parts'
        projected convex hulls (a coarse, fast stand-in for ``tracker.imaging.render``).

        ``parts``: indices of the parts to draw (default all); ``base``: per-view masks to draw
        them onto (e.g. the other parts, rendered once while a search varies one chain)."""
        pose = forward(self.model, params)
        sel = np.arange(self.model.n_parts) if parts is None else np.asarray(parts, dtype=int)
        pts = np.einsum("pij,pmj->pmi", pose.rotation[sel], self._local[sel]) + pose.translation[sel, None, :]
        out = []
        for k, cam in enumerate(self.cameras):
            img = np.zeros((cam.height, cam.width), np.uint8) if base is None else base[k].astype(np.uint8)
            ok = cam.depth(pts) > 0.05
            uv = np.nan_to_num(np.clip(cam.project(pts), -1e5, 1e5)) * 16.0  # 4 fractional bits
            for p in range(len(pts)):
                if ok[p].sum() >= 3:
                    cv2.fillConvexPoly(img, cv2.convexHull(uv[p][ok[p]].astype(np.int32)), 1, shift=4)
            out.append(img.astype(bool))
        return out

    def ious(self, params: np.ndarray, parts: np.ndarray | None = None,
             base: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """Per-camera IoU of the model's silhouette with the observed one, shape (n_cams,)
        (``parts``, ``base``: as ``render``; the IoU is of ``base`` and ``parts`` together)."""
        self.n_scored += 1
        out = []
        for mask, r in zip(self.masks, self.render(params, parts, base)):
            union = np.count_nonzero(r | mask)
            out.append(np.count_nonzero(r & mask) / union if union else 1.0)
        return np.array(out)

    def expected_iou(self, *, loss_per_boundary: float = 0.28) -> float:
        """The mean IoU a correct pose reaches on these views: the scoring loses a share of the
        silhouettes' boundary pixels (polygonal parts, down-scaled masks), so 1 − IoU ≈
        ``loss_per_boundary`` × the fraction of mask pixels on the boundary (hop clip rendered, 4
        and 6 cameras at 320x240 to 800x600: 0.23-0.31; IoU 0.88 at 320x240, 0.93 at 640x480)."""
        kernel = np.ones((3, 3), np.uint8)
        fractions = [1.0 - np.count_nonzero(cv2.erode(m.astype(np.uint8), kernel)) / max(np.count_nonzero(m), 1)
                     for m in self.masks]
        return float(1.0 - loss_per_boundary * np.mean(fractions))

    def score(self, params: np.ndarray, parts: np.ndarray | None = None,
              base: Sequence[np.ndarray] | None = None) -> float:
        """Mean IoU over the cameras (higher is better; ``parts``, ``base``: as ``render``)."""
        return float(self.ious(params, parts, base).mean())


def chamfer_from_silhouette(silhouette: np.ndarray, *, max_distance_px: float = 48.0):
    """``ChamferImages`` of a bare silhouette (its outline doubles as the edge map)."""
    from segmentation.distance import chamfer_images
    from segmentation.edges import silhouette_boundary

    sil = (np.asarray(silhouette) > 0).astype(np.uint8) * 255
    return chamfer_images(sil, silhouette_boundary(sil), max_distance_px=max_distance_px, resolution_px=0.25)


def rendered_views(model: BodyModel, params: np.ndarray, cameras: Sequence[Camera]) -> tuple[dict, dict]:
    """What a perfect segmentation of the model at ``params`` gives (tests, benchmarks): dicts
    camera name -> silhouette (h, w) uint8 and camera name -> ``ChamferImages`` of the silhouette
    and the parts' internal edges (``tracker.imaging.render``)."""
    from segmentation.distance import chamfer_images
    from tracker.imaging.render import internal_edges, render_label_images

    labels = render_label_images(model, forward(model, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    chamfer = {c.name: chamfer_images(sils[c.name], internal_edges(lab), max_distance_px=48.0, resolution_px=0.25)
               for c, lab in zip(cameras, labels)}
    return sils, chamfer


# ----------------------------------------------------------------------------- hypotheses
def model_top_m(model: BodyModel, params: np.ndarray | None = None) -> float:
    """Highest point of the model's surface at ``params`` (default the reference pose), metres."""
    pose = forward(model, model.zero() if params is None else params)
    return float(body_points(model, pose, n_theta=12, n_z=2)[..., 2].max())


def estimate_height(hull: VoxelHull, model: BodyModel) -> float:
    """Subject height from an upright hull: ``model.height_m`` × hull height / the model's reference height."""
    return float(model.height_m * hull.height() / model_top_m(model))


def sized_model(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray], *,
                min_voxel_m: float = 0.02) -> BodyModel:
    """``model`` re-sized to the height of the person the silhouettes show (standing upright,
    e.g. the T/A-pose of an initialisation); use it when the subject's height is not known."""
    cameras, sils, _ = prepare_inputs(model, cameras, silhouettes, None, with_chamfer=False)
    hull = visual_hull(cameras, sils, min_voxel_m=min_voxel_m).largest_component()
    if hull.empty:
        raise ValueError("sized_model: the silhouettes share no volume (empty visual hull)")
    return model.with_height(estimate_height(hull, model))


def feet_direction(hull: VoxelHull, *, sole_m: float = 0.06, shank_m=(0.15, 0.40),
                   min_offset_m: float = 0.04) -> np.ndarray | None:
    """Horizontal unit vector (2,) the feet point to, or None when unclear.

    Feet reach forward of the ankles (toes ~20 cm ahead, heels ~5 cm behind), so in a standing
    subject's hull the volume within ``sole_m`` of the floor is centred ahead of the shanks
    (heights ``shank_m``).  This breaks the front/back symmetry of a T- or A-pose silhouette.
    """
    pts = hull.points()
    z = pts[:, 2] - hull.extent()[0, 2]
    sole, shank = pts[z < sole_m], pts[(z > shank_m[0]) & (z < shank_m[1])]
    if len(sole) == 0 or len(shank) == 0:
        return None
    f = sole[:, :2].mean(0) - shank[:, :2].mean(0)
    n = float(np.linalg.norm(f))
    return f / n if n >= min_offset_m else None


def _index(model: BodyModel, names: Sequence[str]) -> np.ndarray:
    return np.array([model.param_names.index(n) for n in names if n in model.param_names], dtype=int)


def pose_candidates(model: BodyModel, hull: VoxelHull, *, n_headings: int = 12,
                    arm_abduction_deg: Sequence[float] = ARM_POSES_DEG, hint: np.ndarray | None = None,
                    facing: np.ndarray | None = None):
    """Start poses ``[(label, heading_rad, params (n_params,)), ...]`` placed on the hull.

    ``facing`` (2,), e.g. ``feet_direction(hull)``: keep only headings within 90° of it.
    """
    centroid = hull.centroid()
    floor = hull.extent()[0, 2]
    root_t = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    root_r = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    rest = body_points(model, forward(model, model.zero()), n_theta=12, n_z=2)
    sole = float(rest[..., 2].min())  # the model's lowest point at the reference pose (≈ 0)
    _, axes = hull.floor_axes()
    span = np.arctan2(axes[1, 0], axes[0, 0])  # major floor axis: the arms in a T-pose (model +y)
    headings = list(2 * np.pi * np.arange(n_headings) / max(n_headings, 1))
    headings += [span - np.pi / 2, span + np.pi / 2]
    if facing is not None:
        headings = [h for h in headings if np.cos(h) * facing[0] + np.sin(h) * facing[1] > 0.0]
    abd = _index(model, ["left_upper_arm.abduction", "right_upper_arm.abduction"])
    names = {0.0: "T", -45.0: "A"}
    arms = [(names.get(float(a), f"{a:+.0f}"), np.radians(a)) for a in arm_abduction_deg]
    shapes = []
    for left_label, left in arms:  # each arm on its own (one may be missed by a segmentation)
        for right_label, right in arms:
            p = model.zero()
            p[abd] = [left, right]
            shapes.append((left_label if left_label == right_label else f"{left_label}/{right_label}", p))
    if hint is not None:
        h = model.clamp(np.asarray(hint, dtype=float))
        p = model.zero()
        joints = model.param_kind == JOINT_ROTATION
        p[joints] = h[joints]
        shapes.append(("hint", p))
    out = []
    for label, shape in shapes:
        for psi in headings:
            p = shape.copy()
            p[root_t] = [centroid[0], centroid[1], floor - sole]
            p[root_r] = [0.0, 0.0, (psi + np.pi) % (2 * np.pi) - np.pi]
            out.append((label, float(p[root_r][2]), p))
    return out


# ----------------------------------------------------------------------------- refinement
def _subset_fun(fun, x_full: np.ndarray, idx: np.ndarray):
    """Restrict ``fun(x, jacobian) -> (r, J)`` to the parameters ``idx``."""

    def f(xs, jacobian):
        x = x_full.copy()
        x[idx] = xs
        r, J = fun(x, jacobian)
        return r, (None if J is None else J[:, idx])

    return f


def _stages(model: BodyModel) -> list[np.ndarray]:
    root = np.flatnonzero(model.param_kind != JOINT_ROTATION)
    joints = np.flatnonzero(model.param_kind == JOINT_ROTATION)
    return [root, joints, np.arange(model.n_params)]


def refine(model: BodyModel, cameras: Sequence[Camera], chamfer: Sequence, params: np.ndarray, *,
           stages: Sequence[np.ndarray] | None = None, max_iterations: int = 10, n_samples: int = 6,
           f_scale: float = 5.0, truncate_px: float = 30.0, prior_rad: float = 500.0,
           reverse_weight: float = 0.0, ftol: float = 1e-3):
    """Staged bounded LM on the chamfer cost from ``params``; default stages: root, joints, all.

    ``reverse_weight`` > 0 adds the silhouette → model term of ``tracker.fitting.cost`` (pulls a limb back
    onto silhouette it left uncovered); ``ftol``: LM relative cost change to stop at.

    ``prior_rad`` (px² per rad²) holds the joint angles weakly towards ``params``: a straight
    T-pose arm cannot tell clavicle from shoulder rotation, and the hypothesis is the better guess.

    Returns ``(params (n_params,), CostTerms at params)``.
    """
    cost = ChamferCost(model, cameras, chamfer, n_samples=n_samples, truncate_px=truncate_px,
                       reverse_weight=reverse_weight, reverse_samples=150, reverse_min_px=4.0)
    fun = cost.residual_fn(compact=True)
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


def refine_best(model: BodyModel, cameras: Sequence[Camera], chamfer: Sequence, views: ScoreViews, hull: VoxelHull,
                candidates: Sequence, *, keep: int = 2, max_iterations: int = 10, prepare=None,
                prior_rad: float = 500.0, polish: bool = False) -> InitResult:
    """Score ``candidates`` ``[(label, heading, params)]`` by IoU, refine the best ``keep`` with
    ``refine`` (after ``prepare(params, score) -> (params, score)`` if given) and return the
    refined one with the best IoU.  ``polish``: run ``prepare`` once more on the refined winner
    and refine again if that raised its IoU (a limb the first pass left behind)."""
    scores = np.array([views.score(p) for _, _, p in candidates])
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


#: Elbow hypotheses tried by ``elbow_search``, degrees, per DOF name suffix: the forearm bent
#: with the upper arm twisted either way (the bend points forwards, outwards or inwards), and bent
#: with the arm hanging straight down.
ELBOW_SEARCH_DEG = ({"forearm.flexion": 45, "upper_arm.twist": 30}, {"forearm.flexion": 45, "upper_arm.twist": -30},
                    {"forearm.flexion": 45, "upper_arm.twist": 0, "upper_arm.abduction": -100},
                    {"forearm.flexion": 90, "upper_arm.twist": 30})


def elbow_search(model: BodyModel, cameras: Sequence[Camera], chamfer: Sequence, views: ScoreViews,
                 params: np.ndarray, *, options=ELBOW_SEARCH_DEG, max_iterations: int = 8,
                 iou_weight: float = 10.0) -> tuple[np.ndarray, float]:
    """Arms bent at the elbow, which the silhouettes hide: a forearm bent in front of the trunk
    lies inside the trunk's outline, so the IoU of the limb search cannot see it; the internal
    edges of the chamfer cost can.  For each arm in turn every hypothesis of ``options`` (values
    set on the pose, other DOF kept) is refined fully (``refine``: all DOF, the silhouette → model
    term on) and kept when it lowers RMS chamfer residual + ``iou_weight`` × (1 − IoU).
    Returns ``(params, cost)``."""
    cost = ChamferCost(model, cameras, chamfer, n_samples=6, truncate_px=30.0, reverse_weight=1.0,
                       reverse_samples=150, reverse_min_px=4.0)

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


# ----------------------------------------------------------------------------- entry point
def prepare_inputs(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping, chamfer: Mapping | None, *,
                   with_chamfer: bool = True):
    """Validate the views: ``(cameras list, silhouettes list, chamfer list)`` in camera order;
    chamfer images are built from the silhouettes where ``chamfer`` is None (an empty list when
    ``with_chamfer`` is False)."""
    cameras = list(cameras)
    if not cameras:
        raise ValueError("cameras: need at least one camera")
    if not isinstance(silhouettes, Mapping):
        raise TypeError("silhouettes: expected a dict camera name -> (h, w) mask")
    sils = []
    for cam in cameras:
        if cam.name not in silhouettes:
            raise ValueError(f"silhouettes: no mask for camera {cam.name!r}")
        s = np.asarray(silhouettes[cam.name])
        if s.shape != (cam.height, cam.width):
            raise ValueError(f"silhouettes[{cam.name!r}]: shape {s.shape} != (h, w) = {(cam.height, cam.width)}")
        sils.append(s)
    if not with_chamfer:
        chs = []
    elif chamfer is None:
        chs = [chamfer_from_silhouette(s) for s in sils]
    else:
        missing = [c.name for c in cameras if c.name not in chamfer]
        if missing:
            raise ValueError(f"chamfer: no chamfer images for camera(s) {missing}")
        chs = [chamfer[c.name] for c in cameras]
    return cameras, sils, chs


def initialise(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray],
               chamfer: Mapping[str, object] | None = None, *, hint=None, n_headings: int = 12,
               arm_abduction_deg: Sequence[float] = ARM_POSES_DEG, keep: int = 3, min_voxel_m: float = 0.03,
               score_scale: float = 0.5, max_iterations: int = 10, hull_tolerance: int = 0,
               use_feet: bool = True, front_back: bool = True,
               limb_search_both: bool = True, accept_iou: float = 0.87, elbows: bool = True) -> InitResult:
    """Find the pose of a person standing in a T- or A-pose from silhouettes alone.

    Parameters
    ----------
    model : BodyModel (sized; see ``estimate_height`` / ``InitResult.height_m`` to size it)
    cameras : sequence of Camera
    silhouettes : dict camera name -> (h, w) mask, non-zero = body
    chamfer : dict camera name -> ``ChamferImages`` (or any object with ``sample``); default:
        built from the silhouettes (outline as edges)
    hint : (n_params,) optional previous pose (e.g. the last good one): the search is then
        ``tracker.search.recovery.recover`` (the hint moved onto the hull at every heading, its joint
        angles, limb search) together with the T/A hypotheses, after its cheap local stage (accepted
        at a mean silhouette IoU of ``accept_iou``)
    n_headings : evenly spaced headings searched (plus the two from the hull's floor axes)
    arm_abduction_deg : arm poses searched (0 = T, -45 = A)
    keep : candidates refined with LM
    min_voxel_m, hull_tolerance : hull resolution and views a hull point may miss (``visual_hull``)
    use_feet : the feet cue (``feet_direction``): with ``front_back`` a term of the choice between
        the pose and its mirror when the legs are straight; without, only the headings the feet
        point to are searched (unreliable in a crouch, where the shanks lean forward)
    front_back : refine the winner and its mirror (``tracker.search.mirror.resolve_front_back``: turned
        180°, left and right swapped) fully and keep the better; silhouettes hardly tell front
        from back, and the T/A search alone picks the wrong one on a crouch or at low resolution
    limb_search_both : run ``tracker.search.recovery.limb_search`` on both before refining them
    score_scale : image scale of the IoU scoring views
    """
    if hint is not None:  # a previous pose: the any-pose search of tracker.search.recovery
        from tracker.search.recovery import recover

        return recover(model, cameras, silhouettes, chamfer, hint, n_headings=n_headings, keep=keep,
                       min_voxel_m=min_voxel_m, score_scale=score_scale, max_iterations=max_iterations,
                       hull_tolerance=hull_tolerance, front_back=front_back, accept_iou=accept_iou)
    cameras, sils, chs = prepare_inputs(model, cameras, silhouettes, chamfer)
    hull = visual_hull(cameras, sils, min_voxel_m=min_voxel_m, tolerance=hull_tolerance).largest_component()
    if hull.empty:
        raise ValueError("initialise: the silhouettes share no volume (empty visual hull)")
    views = ScoreViews(model, cameras, sils, scale=score_scale)
    facing = feet_direction(hull) if use_feet else None
    cands = pose_candidates(model, hull, n_headings=n_headings, arm_abduction_deg=arm_abduction_deg,
                            facing=None if front_back else facing)
    best = refine_best(model, cameras, chs, views, hull, cands, keep=keep, max_iterations=max_iterations)
    if not front_back:
        return best
    from tracker.search.mirror import resolve_front_back
    from tracker.search.recovery import limb_search

    res = resolve_front_back(model, cameras, silhouettes, chamfer, best.params, views=views,
                             prepared=(cameras, sils, chs), feet_direction=facing,
                             prepare=(lambda p, s: limb_search(model, views, p, s)) if limb_search_both else None)
    if elbows:
        x, _ = elbow_search(model, cameras, chs, views, res.params)
        if not np.array_equal(x, res.params):
            terms = ChamferCost(model, cameras, chs, n_samples=8).evaluate(x)
            res = replace(res, params=x, score=views.score(x), rms_px=terms.rms_px(),
                          inside_fraction=terms.inside_fraction())
            best = replace(best, label=f"{best.label}+elbows")
    return replace(res, label=f"{best.label}/{res.label}", height_m=best.height_m,
                   candidates=views.n_scored, hull=hull)
