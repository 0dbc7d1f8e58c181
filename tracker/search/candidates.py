"""Pose hypotheses from the visual hull, before any least-squares refinement.

* **Placement** (``pose_candidates``): reference poses (T, A, each arm on its own, or a hint's
  joint angles) stood on the hull's floor at its volume centroid and turned to evenly spaced
  headings plus the two that put the arms' span along the hull's major floor axis
  (BMVC'04 §4: a reference pose placed from the voxels' moments).  ``hull_placements`` moves a
  given pose (the last good one) onto the hull the same way.
* **Size** (``estimate_height``, ``sized_model``): the subject's height from an upright hull.
* **Feet** (``feet_direction``): feet reach forward of the ankles, so the hull's sole layer lies
  ahead of its shanks; a cue for front against back while the legs are straight.
* **Limbs** (``limb_search``): a greedy search per chain (arms, legs, trunk) over alternative
  angle sets, scored by silhouette IoU with the rest of the body fixed.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from capture.camera import Camera, matrix_to_rodrigues
from tracker.body.kinematics import forward, so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.imaging.render import body_points
from tracker.search.hull import VoxelHull, visual_hull
from tracker.search.scoring import ScoreViews, prepare_inputs

__all__ = ["ARM_POSES_DEG", "pose_candidates", "hull_placements", "turn_about_vertical", "body_centroid",
           "model_top_m", "estimate_height", "sized_model", "feet_direction", "limb_chains", "limb_search",
           "ARM_SEARCH_DEG", "LEG_SEARCH_DEG"]

#: Arm abductions tried by default (degrees; 0 = T-pose, negative lowers the arms).
ARM_POSES_DEG = (0.0, -45.0)

#: Canonical limb poses tried by the limb search, degrees, per DOF name suffix (other DOF of the
#: chain 0).  The models mirror the right side's axes, so one table serves both sides.
ARM_SEARCH_DEG = tuple({"upper_arm.abduction": a, "upper_arm.flexion": f}
                      for a in (-80, -45, 0, 35, 70) for f in (-40, 0, 50) if (a, f) != (0, 0)) + (
                 {"upper_arm.abduction": -45, "forearm.flexion": 70}, {"upper_arm.flexion": 60, "forearm.flexion": 70})
LEG_SEARCH_DEG = ({"thigh.flexion": 30}, {"thigh.flexion": -15}, {"thigh.abduction": 20},
                 {"thigh.flexion": 45, "shank.flexion": 60}, {"shank.flexion": 45})


# ----------------------------------------------------------------------------- size and feet
def model_top_m(model: BodyModel, params: np.ndarray | None = None) -> float:
    """Highest point of the model's surface, metres (world z).

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,), optional
        The pose (default the reference pose).

    Returns
    -------
    float
    """
    pose = forward(model, model.zero() if params is None else params)
    return float(body_points(model, pose, n_theta=12, n_z=2)[..., 2].max())


def estimate_height(hull: VoxelHull, model: BodyModel) -> float:
    """Subject height from an upright hull: ``model.height_m`` × hull height / the model's top.

    Parameters
    ----------
    hull : VoxelHull
    model : BodyModel

    Returns
    -------
    float
        Height in metres.
    """
    return float(model.height_m * hull.height() / model_top_m(model))


def sized_model(model: BodyModel, cameras: Sequence[Camera], silhouettes: Mapping[str, np.ndarray], *,
                min_voxel_m: float = 0.02) -> BodyModel:
    """``model`` re-sized to the height of the person the silhouettes show.

    The person must stand upright (e.g. the T/A-pose of an initialisation); use it when the
    subject's height is not known.

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera
    silhouettes : mapping str -> ndarray, shape (h, w)
        Camera name -> mask, non-zero = body.
    min_voxel_m : float
        Finest voxel size of the hull, metres.

    Returns
    -------
    BodyModel

    Raises
    ------
    ValueError
        The silhouettes share no volume.
    """
    inputs = prepare_inputs(model, cameras, silhouettes, None, with_chamfer=False)
    hull = visual_hull(inputs.cameras, inputs.silhouettes, min_voxel_m=min_voxel_m).largest_component()
    if hull.empty:
        raise ValueError("sized_model: the silhouettes share no volume (empty visual hull)")
    return model.with_height(estimate_height(hull, model))


def feet_direction(hull: VoxelHull, *, sole_m: float = 0.06, shank_m=(0.15, 0.40),
                   min_offset_m: float = 0.04) -> np.ndarray | None:
    """Horizontal direction the feet point to, from a standing subject's hull.

    Feet reach forward of the ankles, so the volume within ``sole_m`` of the floor is centred
    ahead of the shanks.  This breaks the front/back symmetry of a T- or A-pose silhouette.

    Parameters
    ----------
    hull : VoxelHull
    sole_m : float
        Height of the sole layer above the hull's lowest point, metres.
    shank_m : (float, float)
        Height range of the shank layer, metres.
    min_offset_m : float
        Smallest horizontal offset of the sole layer's centre from the shanks' that counts, metres.

    Returns
    -------
    ndarray, shape (2,), or None
        Unit vector in the floor plane; None when unclear.
    """
    pts = hull.points()
    z = pts[:, 2] - hull.extent()[0, 2]
    sole, shank = pts[z < sole_m], pts[(z > shank_m[0]) & (z < shank_m[1])]
    if len(sole) == 0 or len(shank) == 0:
        return None
    f = sole[:, :2].mean(0) - shank[:, :2].mean(0)
    n = float(np.linalg.norm(f))
    return f / n if n >= min_offset_m else None


# ----------------------------------------------------------------------------- placement
def _index(model: BodyModel, names: Sequence[str]) -> np.ndarray:
    return np.array([model.param_names.index(n) for n in names if n in model.param_names], dtype=int)


def pose_candidates(model: BodyModel, hull: VoxelHull, *, n_headings: int = 12,
                    arm_abduction_deg: Sequence[float] = ARM_POSES_DEG, hint: np.ndarray | None = None,
                    facing: np.ndarray | None = None) -> list[tuple[str, float, np.ndarray]]:
    """Reference poses placed on the hull at every searched heading.

    Parameters
    ----------
    model : BodyModel
    hull : VoxelHull
    n_headings : int
        Evenly spaced headings (the two of the hull's major floor axis are added).
    arm_abduction_deg : sequence of float
        Arm abductions, degrees (0 = T, -45 = A); each arm takes each on its own.
    hint : ndarray, shape (n_params,), optional
        A pose whose joint angles are one more shape.
    facing : ndarray, shape (2,), optional
        E.g. ``feet_direction(hull)``: keep only headings within 90° of it.

    Returns
    -------
    list of (label, heading_rad, params)
        ``label`` names the shape (``"T"``, ``"A"``, ``"T/A"``: left T, right A, ``"hint"``);
        ``params`` has shape (n_params,).
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


def turn_about_vertical(model: BodyModel, params: np.ndarray, angle_rad: float, pivot: np.ndarray) -> np.ndarray:
    """The pose turned about a vertical line.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    angle_rad : float
        Turn about +z, radians.
    pivot : ndarray, shape (3,)
        A point of the vertical line, world metres.

    Returns
    -------
    ndarray, shape (n_params,)
    """
    p = np.array(params, dtype=float)
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    r_idx = np.flatnonzero(model.param_kind == ROOT_ROTATION)
    Rz = so3_exp(np.array([0.0, 0.0, angle_rad]))
    R = Rz @ so3_exp(p[r_idx])
    p[t_idx] = pivot + Rz @ (p[t_idx] - pivot)
    p[r_idx] = matrix_to_rodrigues(R)
    return p


def body_centroid(model: BodyModel, params: np.ndarray) -> np.ndarray:
    """Mean of points spread over the model's surface.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)

    Returns
    -------
    ndarray, shape (3,)
        World metres.
    """
    return body_points(model, forward(model, params), n_theta=8, n_z=2).reshape(-1, 3).mean(0)


def hull_placements(model: BodyModel, params: np.ndarray, hull: VoxelHull,
                    n_headings: int) -> list[tuple[str, float, np.ndarray]]:
    """A pose moved horizontally onto the hull's centroid and turned about the vertical through it.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    hull : VoxelHull
    n_headings : int
        Evenly spaced turns, the first 0.

    Returns
    -------
    list of ("last", turn_rad, params)
        As ``pose_candidates``.
    """
    moved = params.copy()
    shift = hull.centroid() - body_centroid(model, params)
    shift[2] = 0.0
    moved[np.flatnonzero(model.param_kind == ROOT_TRANSLATION)] += shift
    pivot = body_centroid(model, moved)
    return [("last", float(a), turn_about_vertical(model, moved, a, pivot))
            for a in 2 * np.pi * np.arange(n_headings) / n_headings]


# ----------------------------------------------------------------------------- limbs
def limb_chains(model: BodyModel) -> dict[str, np.ndarray]:
    """Joint-parameter indices per chain.

    Parameters
    ----------
    model : BodyModel

    Returns
    -------
    dict str -> ndarray of int
        ``left_arm``, ``right_arm``, ``left_leg``, ``right_leg`` and ``trunk`` (every other joint DOF).
    """
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
    """Greedy per-chain search, scored by IoU with the rest of the body fixed.

    Each chain (``limb_chains``) tries its current angles halved, zeroed, mirrored from the other
    side, and the canonical ``arm_poses`` / ``leg_poses``; a better IoU is kept at once.

    Parameters
    ----------
    model : BodyModel
    views : ScoreViews
    params : ndarray, shape (n_params,)
    score : float
        The IoU of ``params`` on ``views``.
    arm_poses, leg_poses : sequence of dict str -> float
        Canonical angle sets, degrees per DOF name suffix (``ARM_SEARCH_DEG``, ``LEG_SEARCH_DEG``).

    Returns
    -------
    params : ndarray, shape (n_params,)
    score : float
        Its mean IoU.
    """
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
        # the options differ from x only in the chain's angles (and clamp is per parameter), so
        # they are scored together and taken in order as if one after the other
        tried = []
        for vals in options:
            y = x.copy()
            y[idx] = vals
            tried.append(model.clamp(y))
        for y, s in zip(tried, views.scores(tried, np.flatnonzero(moved), base)):
            if s > score:
                x, score = y, float(s)
    return x, score
