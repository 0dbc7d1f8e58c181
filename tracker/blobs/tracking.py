"""The blob tracker: coloured hull, EM blobs and inverse kinematics per frame (BMVC'04 §3.3–4).

Per frame set (camera name → BGR image):

1. predict the pose (the last one, or extrapolated with ``velocity_gain``) and reconstruct the coloured hull
   (``tracker.blobs.colour_hull``) in the zone of interest around it;
2. ``em_iterations`` times: re-create the blobs on the model at the current pose
   (``BlobSet.regenerate``), assign voxels to blobs (``tracker.blobs.em.expectation``, eq. 2;
   by default each voxel is shared among its nearest blobs rather than given to one, which keeps a
   blob that slipped onto a neighbour's voxels from locking there), re-estimate them
   (``maximisation``, eq. 4; ``BlobSet.absorb`` blends colour with its prior and
   de-activates blobs whose filling falls below ``min_fill``), and move the model onto the active
   blobs' means: the root by least squares on the trunk's blobs with the previous orientation as
   a constraint, then the limbs and the root together by damped least squares (or the limbs by the
   paper's cyclic coordinate descent) within the joint limits (``tracker.blobs.ik``); after the
   last round, the floor contact;
3. emit a DESIGN.md pose record (``"method": "blobs"``).

The blobs are learned from the first frame's hull at the initial pose (``initial_params``, or the
pose an ``initialiser`` finds, e.g. ``tracker.blobs.start.ContourStart``: the contour tracker's
first frames, whose poses are reported until it hands over, or :func:`initialise_from_images`).
The hull's shadow-like samples go through the multi-view floor test (``BlobOptions.floor_test``).  A frame is ``ok: false`` when the hull in the zone is nearly
empty, too few blobs are active, the active blobs' means are far from where the fitted model
puts them, a part of the fitted model lies outside the hull (``BlobOptions.min_part_support``), or
much of the hull lies outside the fitted model (``max_unexplained``); the fit is still the next
frame's start, without velocity.  Never raises on data.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Mapping, Sequence

import numpy as np

from capture.camera import Camera
from segmentation.background import BackgroundModel
from tracker.blobs.blobset import BlobSet, blob_layout, learn_blobs
from tracker.blobs.colour_hull import ColourHull, HullOptions, coloured_hull, zone_of_interest
from tracker.blobs.em import expectation, maximisation
from tracker.blobs.floor_samples import SampleFloorTest
from tracker.blobs.props import carve
from tracker.blobs.start import StartPending
from tracker.blobs.static_voxels import StaticVoxels
from tracker.blobs.walk_heading import WalkHeading, speed_weight
from tracker.blobs.leg_velocity import LegVelocity
from tracker.blobs.kernels import cones_contain, lattice_member
from tracker.blobs.ik import ccd, damped_least_squares, fit_root, floor_contact
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import JOINT_ROTATION, ROOT_TRANSLATION, BodyModel
from tracker.search.candidates import turn_about_vertical

__all__ = ["BlobOptions", "BlobTracker", "initialise_from_images"]

_ROOT_BLOBS = ("pelvis", "abdomen", "torso.0")


@dataclass(frozen=True)
class BlobOptions:
    """Options of :class:`BlobTracker`. hull : ``HullOptions`` of the coloured hull; zone_margin_m : the zone of
    interest around the predicted body surface; em_iterations : expectation–maximisation–IK rounds per frame;
    colour_weight : factor on the colour term of eq. 2; log_det : add the Gaussians' log-determinants to eq. 2
    (``tracker.blobs.em.expectation``); soft : share each voxel among its ``soft`` nearest blobs instead of the paper's
    hard assignment (0); gate : largest position term of an assigned voxel (squared Mahalanobis); motion_sigma_m :
    spread added to every blob's position covariance in the expectation (the uncertainty of the predicted pose: a limb
    a few cm off its prediction still reaches its voxels); min_fill : filling below which a blob is inactive;
    colour_prior_weight, skin_prior_weight : how much a blob's colour is pulled back to its prior each frame (skin
    blobs: face and hands); ik : ``"ccd"`` or ``"dls"``; ccd_sweeps, ccd_attenuation, ccd_damping :
    ``tracker.blobs.ik.ccd``; dls_iterations, dls_damping : ``damped_least_squares``; dls_root : the root moves in it
    too (the legs' goals lower the trunk into a crouch); root_blobs : the rigid root fit's blobs; offset_weight,
    max_offset_m : ``learn_blobs``' learnt attachment offsets (0: none); orientation_weight, max_turn_deg : the root's
    orientation constraint (``fit_root``); floor_snap_m : ``floor_contact`` (None: no floor constraint); velocity_gain
    : predict ``p_t + g (p_t − p_{t−1})`` (0: the last pose; the contour tracker uses 1, but blob fits are noisier than
    contour fits and the extrapolation amplifies their noise); min_voxels, min_active_fraction, max_goal_rms_m :
    below/above these a frame is ``ok: false``; min_part_support : a frame is ``ok: false`` when some part (clavicles
    aside) has less than this fraction of its interior points (its cone shrunk to half its radii) in the hull, within
    half a finest voxel (:func:`hull_support`): a limb the fit put where the cameras see background (or where nothing
    was reconstructed) is not explained by the images, however well the blobs fit (0: no such test); max_unexplained :
    a frame is ``ok: false`` when more than this fraction of the hull's volume lies outside the fitted body (every part
    grown by a finest voxel, :func:`body_contains`): the fit leaves much of what the cameras see unexplained (a limb
    reconstructed where the model has none, or a hull too coarse to constrain the pose; 1: no such test); floor_test :
    the hull's shadow-like samples go through ``tracker.blobs.floor_samples`` (2+ cameras); static_scene : voxels of
    lattice cubes that stay occupied away from the fitted body are left out of the EM and of the unexplained volume
    (``tracker.blobs.static_voxels``, with ``static_rate``, ``static_threshold``, ``static_clearance_m``; e.g. a chair
    not in the background); prop_weight : with ``props``, the damped least squares' residual per metre a part comes too
    near a prop (``tracker.blobs.props``; goals: metres × √weight); arm_goals_move : what the arm goals pull in the
    damped least squares (:func:`arm_goal_moves`); walk_*, leg_velocity_* : ``tracker.blobs.walk_heading`` (start
    turned toward the walk; source: pelvis joint or hull centroid), ``tracker.blobs.leg_velocity`` (a gain 0: that cue off).
    """

    hull: HullOptions = field(default_factory=HullOptions)
    zone_margin_m: float = 0.25
    em_iterations: int = 2
    colour_weight: float = 1.0
    log_det: bool = False
    soft: int = 3
    gate: float = 25.0
    motion_sigma_m: float = 0.04
    min_fill: float = 0.3
    colour_prior_weight: float = 0.2
    skin_prior_weight: float = 0.5
    ik: str = "dls"
    ccd_sweeps: int = 3
    ccd_attenuation: float = 1.0
    ccd_damping: float = 1e-4
    dls_iterations: int = 3
    dls_damping: float = 1e-3
    orientation_weight: float = 0.02
    max_turn_deg: float = 60.0
    floor_snap_m: float | None = 0.02
    velocity_gain: float = 0.0
    min_voxels: int = 50
    min_active_fraction: float = 0.6
    max_goal_rms_m: float = 0.045
    min_part_support: float = 0.4
    max_unexplained: float = 0.4
    floor_test: bool = True
    offset_weight: float = 0.0
    root_blobs: tuple = _ROOT_BLOBS
    dls_root: bool = True
    max_offset_m: float = 0.05
    static_scene: bool = True
    static_rate: float = 0.05
    static_threshold: float = 0.7
    static_clearance_m: float = 0.1
    prop_weight: float = 10.0
    arm_goals_move: str = "all"
    walk_gain: float = 0.1
    walk_speed_min: float = 0.3
    walk_speed_full: float = 0.6
    walk_window_s: float = 0.3
    walk_max_deg: float = 180.0
    walk_source: str = "fit"
    walk_upright: float = 0.0
    walk_dead_deg: float = 0.0
    leg_velocity_gain: float = 1.0
    leg_velocity_frames: int = 3
    leg_velocity_flexion_only: bool = True
    leg_velocity_antiphase: bool = True

    def __post_init__(self):
        if self.arm_goals_move not in ("all", "twist", "arm"):
            raise ValueError(f"arm_goals_move: expected 'all', 'twist' or 'arm', got {self.arm_goals_move!r}")
        if self.walk_source not in ("fit", "hull"):
            raise ValueError(f"walk_source: expected 'fit' or 'hull', got {self.walk_source!r}")
        if self.ik not in ("ccd", "dls"):
            raise ValueError(f"ik: expected 'ccd' or 'dls', got {self.ik!r}")
        if int(self.em_iterations) < 1:
            raise ValueError(f"em_iterations: expected >= 1, got {self.em_iterations!r}")


def _interior_samples(model: BodyModel, *, n_theta: int = 8, n_z: int = 5,
                      radius_fraction: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points inside every part but the clavicles: ``n_theta × n_z`` points on each cone shrunk to
    ``radius_fraction`` of its radii.  Returns (parts (p,), part of each point (p m,), points in
    their part's frame (p m, 3))."""
    from tracker.imaging.render import cone_points

    parts = np.array([i for i, n in enumerate(model.part_names) if "clavicle" not in n])
    local = cone_points(model, n_theta=n_theta, n_z=n_z)[parts].copy()
    local[..., :2] *= radius_fraction
    return parts, np.repeat(parts, local.shape[1]), local.reshape(-1, 3)


_ARM_PARTS = ("clavicle", "upper_arm", "forearm", "hand")
_SPINE_PARTS = ("abdomen", "torso")


def arm_goal_moves(model: BodyModel, part: np.ndarray, *, twist: bool = False) -> np.ndarray:
    """Which parameters a goal on each part (``part`` (m,) part indices) may pull, (m, n_params) bool.

    Any goal off the arms: every parameter.  A goal on an arm part: only its own arm's joints (the arm
    parts it hangs from), or with ``twist`` every parameter but the spine's twists (the abdomen's and
    torso's rotations about their long axis): arm blobs lagging a quick arm motion do not twist the
    spine directly (other goals still may).  ``BlobOptions.arm_goals_move``: ``"all"`` (no mask), ``"twist"``, ``"arm"``.
    """
    part = np.asarray(part, dtype=int)
    names = model.part_names
    arm_part = np.array([any(a in n for a in _ARM_PARTS) for n in names])
    on_arm = arm_part[part]
    moves = np.ones((len(part), model.n_params), bool)
    if twist:
        spine = np.isin(np.asarray(names)[model.param_part], _SPINE_PARTS)
        along = np.abs(np.asarray(model.param_axis, dtype=float)[:, 2]) > 0.99
        moves[np.ix_(on_arm, spine & along & (model.param_kind == JOINT_ROTATION))] = False
    else:
        moves[on_arm] = model.affects[part[on_arm]] & arm_part[model.param_part][None, :]
    return moves


def hull_support(hull: ColourHull, points: np.ndarray, *, tolerance_m: float = 0.0) -> np.ndarray:
    """Whether each point (m, 3) lies in a cube of the coloured hull, or within ``tolerance_m`` of one
    along an axis; (m,) bool.  The hull's cubes lie on the world lattice of their size
    (``coloured_hull``), so each size is one lookup in a grid."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if tolerance_m > 0:
        offsets = np.vstack([np.zeros(3), tolerance_m * np.eye(3), -tolerance_m * np.eye(3)])
        P = (P[None] + offsets[:, None]).reshape(-1, 3)
    inside = np.zeros(len(P), bool)
    for size in np.unique(hull.sizes):
        cells = np.floor(hull.centres[hull.sizes == size] / size).astype(np.int64)
        inside |= lattice_member(cells, np.floor(P / size).astype(np.int64))
    n = len(np.asarray(points).reshape(-1, 3))
    return inside.reshape(-1, n).any(0)


def body_contains(model: BodyModel, pose, points: np.ndarray, *, margin_m=0.0) -> np.ndarray:
    """Whether each point (m, 3) lies in some part's cone (radii and ends grown by ``margin_m``) at
    ``pose``; (m,) bool, or (k, m) for a sequence of k margins (one pass over the points)."""
    P = np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3))
    margins = np.atleast_1d(np.asarray(margin_m, dtype=float))
    inside = cones_contain(np.ascontiguousarray(model.cones, dtype=float), np.ascontiguousarray(pose.rotation),
                           np.ascontiguousarray(pose.translation), P, margins)
    return inside[0] if np.ndim(margin_m) == 0 else inside


def initialise_from_images(model: BodyModel, cameras: Sequence[Camera], images: Mapping[str, np.ndarray],
                           backgrounds: Mapping[str, BackgroundModel], *, refine: bool = True,
                           floor_test: bool = True) -> np.ndarray:
    """A first pose from one frame set, as the contour tracker finds its own; returns params (n_params,).

    The frames are segmented with the multi-view floor test of shadow-like pixels
    (``segmentation.floor``, when ``floor_test`` and there are at least two cameras: dark clothes on a
    dark floor are otherwise taken for shadow), the silhouette search
    (``tracker.search.initialise.initialise``) finds a pose, and with ``refine`` the contour tracker
    fits it to the silhouettes' contours and settles front/back from the colours
    (``tracker.fitting.tracking.Tracker``'s first frame with its front/back guard): the blobs are
    learnt at this pose, so an error here persists.  Raises ValueError on failure.
    """
    from segmentation.floor import FloorShadows
    from segmentation.pipeline import segment_frame
    from tracker.fitting.tracking import Tracker
    from tracker.search.initialise import initialise

    floor = None
    if floor_test and len(cameras) >= 2:
        floor = FloorShadows(cameras, {c.name: backgrounds[c.name] for c in cameras})
    segs = {c.name: segment_frame(backgrounds[c.name], images[c.name],
                                  floor=None if floor is None else floor.for_camera(c.name, images))
            for c in cameras}
    sils = {n: s.silhouette for n, s in segs.items()}
    chs = {n: s.chamfer for n, s in segs.items()}
    if not refine:
        return model.clamp(np.asarray(initialise(model, cameras, sils, chs).params, dtype=float))
    record = Tracker(model, cameras).step(0, 0, chs, silhouettes=sils, images={c.name: images[c.name] for c in cameras})
    if "params" not in record:
        raise ValueError(record.get("reason", "no pose"))
    return model.clamp(np.asarray(record["params"], dtype=float))


class BlobTracker:
    """Frame-to-frame blob tracker of one person (module docstring).

    Parameters
    ----------
    model : BodyModel
    cameras : sequence of Camera (the studio; a frame may bring any subset)
    backgrounds : camera name -> BackgroundModel
    initial_params : (n_params,) the first frame's pose, or None to use ``initialiser``
    initialiser : callable ``(cameras, images) -> params`` run on the first frame when there is no
        ``initial_params`` (may raise ValueError)
    options : BlobOptions
    clock : callable returning seconds, default ``time.perf_counter``
    props : sequence of ``tracker.fitting.props.PropBox``, world boxes never body (``tracker.blobs.props``)

    Attributes
    ----------
    params : (n_params,) the last fitted pose (None before initialisation)
    blobs : BlobSet (None before initialisation)
    last_hull : ColourHull of the last frame (for display)
    """

    def __init__(self, model: BodyModel, cameras: Sequence[Camera], backgrounds: Mapping[str, BackgroundModel], *,
                 initial_params=None, initialiser: Callable | None = None, options: BlobOptions = BlobOptions(),
                 clock: Callable[[], float] = time.perf_counter, props: Sequence = ()) -> None:
        self.model = model
        self.props = list(props)
        self._prop_penalty = None
        if self.props:
            from tracker.fitting.props import PropPenalty

            self._prop_penalty = PropPenalty(self.props, weight=options.prop_weight)
        self.cameras = {c.name: c for c in cameras}
        if len(self.cameras) != len(cameras):
            raise ValueError("cameras: names must be unique")
        missing = [n for n in self.cameras if n not in backgrounds]
        if missing:
            raise ValueError(f"backgrounds: no model for camera(s) {missing}")
        self.backgrounds = dict(backgrounds)
        self.options = options
        self.initialiser = initialiser
        self.clock = clock
        self.layout = blob_layout(model)
        self.blobs: BlobSet | None = None
        self.params: np.ndarray | None = None
        self.previous: np.ndarray | None = None
        self.last_hull: ColourHull | None = None
        if initial_params is not None:
            p = np.asarray(initial_params, dtype=float)
            if p.shape != (model.n_params,) or not np.all(np.isfinite(p)):
                raise ValueError(f"initial_params: expected a finite array of shape ({model.n_params},)")
            self.params = model.clamp(p)
        names = self.layout.names
        self._motion = options.motion_sigma_m**2 * np.eye(3)
        self._root_blobs = np.array([any(n == r for r in options.root_blobs) for n in names])
        kind = model.param_kind
        self._free = (kind == JOINT_ROTATION) & ~np.array(["clavicle" in model.part_names[p]
                                                           for p in model.param_part])
        self._moves = (None if options.arm_goals_move == "all" else
                       arm_goal_moves(model, self.layout.part, twist=options.arm_goals_move == "twist"))
        self._prior_weight = np.where(self.layout.skin, options.skin_prior_weight, options.colour_prior_weight)
        self._support_parts, self._support_part, self._support_local = _interior_samples(model)
        self._static = (StaticVoxels(options.hull.min_voxel_m, rate=options.static_rate,
                                     threshold=options.static_threshold, clearance_m=options.static_clearance_m)
                        if options.static_scene else None)
        # the pelvis's walk: the yaw cue's, and the speed weight of the legs' rate
        self._walk = (WalkHeading(model, gain=options.walk_gain, speed_min=options.walk_speed_min,
                                  speed_full=options.walk_speed_full, window_s=options.walk_window_s,
                                  max_rad=np.radians(options.walk_max_deg), upright=options.walk_upright,
                                  dead_rad=np.radians(options.walk_dead_deg))
                      if options.walk_gain > 0 or options.leg_velocity_gain > 0 else None)
        self._legs = (LegVelocity(model, gain=options.leg_velocity_gain, frames=options.leg_velocity_frames,
                                  flexion_only=options.leg_velocity_flexion_only,
                                  antiphase=options.leg_velocity_antiphase)
                      if options.leg_velocity_gain > 0 else None)
        self._floor = (SampleFloorTest(cameras, self.backgrounds, low=options.hull.low)
                       if options.floor_test and len(self.cameras) >= 2 else None)

    def predict(self) -> np.ndarray | None:
        """Start pose for the next frame (n_params,) or None before initialisation."""
        if self.params is None:
            return None
        if self.options.velocity_gain > 0 and self.previous is not None:
            return self.model.clamp(self.params + self.options.velocity_gain * (self.params - self.previous))
        return self.params

    def _hull(self, cams, images, params) -> ColourHull:
        zone = zone_of_interest(self.model, params, margin_m=self.options.zone_margin_m)
        hull = coloured_hull(cams, [images[c.name] for c in cams], [self.backgrounds[c.name] for c in cams], zone,
                             options=self.options.hull,
                             floor=None if self._floor is None else self._floor.for_frame(images))
        return carve(hull, self.props)

    def _ik(self, params: np.ndarray, goals: np.ndarray, weights: np.ndarray) -> np.ndarray:
        o, lay, m = self.options, self.layout, self.model
        wr = weights * self._root_blobs
        params = fit_root(m, params, lay.part, self.blobs.point, goals, wr, orientation_weight=o.orientation_weight,
                          max_turn_rad=np.radians(o.max_turn_deg))
        if o.ik == "ccd":
            params = ccd(m, params, lay.part, self.blobs.point, goals, weights, free=self._free, sweeps=o.ccd_sweeps,
                         attenuation=o.ccd_attenuation, damping=o.ccd_damping)
        else:
            params = damped_least_squares(m, params, lay.part, self.blobs.point, goals, weights, free=self._free,
                                          iterations=o.dls_iterations, damping=o.dls_damping, root=o.dls_root,
                                          penalty=self._prop_penalty, moves=self._moves)
        return params

    def part_support(self, hull: ColourHull, pose) -> np.ndarray:
        """Per part (``model.part_names`` but the clavicles, in order) the fraction of its interior
        points in ``hull`` at ``pose`` (a ``Pose`` or params), within half a finest voxel; shape (p,)."""
        if not hasattr(pose, "to_world"):
            pose = forward(self.model, np.asarray(pose, dtype=float))
        inside = hull_support(hull, pose.to_world(self._support_part, self._support_local),
                              tolerance_m=0.5 * hull.min_voxel_m)
        return inside.reshape(len(self._support_parts), -1).mean(1)

    def static(self, hull: ColourHull) -> np.ndarray:
        """Which of the hull's voxels are static scene (``BlobOptions.static_scene``); (n,) bool."""
        if self._static is None:
            return np.zeros(hull.n_voxels, bool)
        return self._static.static(hull.centres)

    def explains(self, hull: ColourHull, pose, scene: np.ndarray | None = None, inside: np.ndarray | None = None
                 ) -> dict:
        """How a pose (``Pose`` or params) and a hull explain each other: ``unexplained`` (fraction of
        the hull's volume, but the ``scene`` voxels (n,) bool, outside every part grown by a finest
        voxel; ``inside`` (n,) bool: that :func:`body_contains` when the caller has it), ``support_min``
        (the smallest :meth:`part_support`) and ``support_min_part`` (its part's name)."""
        if not hasattr(pose, "to_world"):
            pose = forward(self.model, np.asarray(pose, dtype=float))
        vol = hull.volumes if scene is None else np.where(scene, 0.0, hull.volumes)
        if inside is None:
            inside = body_contains(self.model, pose, hull.centres, margin_m=hull.min_voxel_m)
        outside = ~inside
        support = self.part_support(hull, pose)
        worst = int(np.argmin(support))
        return {"unexplained": float(vol[outside].sum() / vol.sum()) if vol.sum() > 0 else 1.0,
                "support_min": float(support[worst]), "support_min_part": self.support_parts[worst]}

    @property
    def support_parts(self) -> tuple:
        """Names of the parts :meth:`part_support` reports, in its order."""
        return tuple(self.model.part_names[p] for p in self._support_parts)

    def fit(self, hull: ColourHull, start: np.ndarray) -> tuple[np.ndarray, dict]:
        """EM and IK rounds on one hull from ``start``; returns params and quality figures."""
        o, m, blobs = self.options, self.model, self.blobs
        params = start
        goals = weights = None
        scene = self.static(hull)
        if np.count_nonzero(~scene) < o.min_voxels:  # nothing left for the body: trust no scene memory
            scene = np.zeros_like(scene)
        body = ~scene
        centres, colours, sizes = hull.centres[body], hull.colours[body], hull.sizes[body]
        for _ in range(int(o.em_iterations)):
            pose = forward(m, params)
            blobs.regenerate(m, pose)
            asg = expectation(centres, colours, blobs.mean, blobs.cov + self._motion, blobs.colour, blobs.colour_cov,
                              colour_weight=o.colour_weight, gate=o.gate, log_det=o.log_det, soft=o.soft)
            stats = maximisation(asg, centres, sizes, self.layout.n_blobs)
            blobs.absorb(stats, colour_prior_weight=self._prior_weight, min_fill=o.min_fill)
            weights = np.where(blobs.active, np.minimum(blobs.fill, 1.0), 0.0)
            goals = np.where(blobs.active[:, None], np.nan_to_num(stats.mean), blobs.mean)
            params = self._ik(params, goals, weights)
        if o.floor_snap_m is not None:
            params = floor_contact(m, params, snap_m=o.floor_snap_m)
        pose = forward(m, params)
        at = blobs.attachment(m, pose)
        act = weights > 0
        rms = float(np.sqrt(np.mean(np.sum((at[act] - goals[act]) ** 2, 1)))) if act.any() else float("nan")
        margins = [hull.min_voxel_m] + ([self._static.clearance_m] if self._static is not None else [])
        inside = body_contains(m, pose, hull.centres, margin_m=margins)  # the gate's and the static memory's
        if self._static is not None:
            self._static.update(hull.centres, ~inside[1])
        return params, {"active_fraction": float(act.mean()), "goal_rms_m": rms, "static_fraction": float(scene.mean()),
                        **self.explains(hull, pose, scene, inside[0])}

    def judge(self, quality: dict) -> list:
        """Why a fit with these quality figures (``fit``'s) is not ok; empty when it is (``BlobOptions``)."""
        o = self.options
        why = []
        if quality["active_fraction"] < o.min_active_fraction:
            why.append(f"{100 * quality['active_fraction']:.0f}% of blobs active < {100 * o.min_active_fraction:.0f}%")
        if quality["unexplained"] > o.max_unexplained:
            why.append(f"{100 * quality['unexplained']:.0f}% of the hull outside the body > "
                       f"{100 * o.max_unexplained:.0f}%")
        if quality["support_min"] < o.min_part_support:
            why.append(f"{quality['support_min_part']} outside the hull ({100 * quality['support_min']:.0f}% of its "
                       f"interior in it < {100 * o.min_part_support:.0f}%)")
        if not quality["goal_rms_m"] <= o.max_goal_rms_m:
            why.append(f"blob goals {1e3 * quality['goal_rms_m']:.0f} mm off > {1e3 * o.max_goal_rms_m:.0f}")
        return why

    def step(self, frame_id: int, timestamp_ns: int, images: Mapping[str, np.ndarray]) -> dict:
        """Fit one frame set (camera name → BGR uint8 image) and return its pose record."""
        t0 = self.clock()
        o = self.options
        record = {"frame": int(frame_id), "timestamp_ns": int(timestamp_ns), "model": self.model.name,
                  "method": "blobs"}
        unknown = sorted(n for n in images if n not in self.cameras)
        names = [n for n in self.cameras if n in images]
        record["cameras"] = len(names)

        def fail(reason: str) -> dict:
            record.update(ok=False, reason=reason, latency_ms=1e3 * (self.clock() - t0))
            return record

        if unknown:
            return fail(f"unknown camera(s) {unknown}")
        if not names:
            return fail("no camera")
        cams = [self.cameras[n] for n in names]
        start = self.predict()
        if start is not None and self._legs is not None:
            start = self._legs.start(start, speed_weight(self._walk.velocity(), speed_min=o.walk_speed_min,
                                                         speed_full=o.walk_speed_full))
        if start is not None and o.walk_gain > 0:
            angle = self._walk.turn(start)
            if angle:
                start = turn_about_vertical(self.model, start, angle,
                                            start[self.model.param_kind == ROOT_TRANSLATION])
        if start is None:
            if self.initialiser is None:
                return fail("no initial pose: pass initial_params or an initialiser")
            try:
                start = self.model.clamp(np.asarray(self.initialiser(cams, images), dtype=float))
            except StartPending as exc:  # the initialiser's own pose while it settles the first one
                for key in ("params", "joints", "ok"):
                    if key in exc.record:
                        record[key] = exc.record[key]
                record["start"] = "pending"
                return fail(f"starting: {exc}") if not record.get("ok") else {
                    **record, "latency_ms": 1e3 * (self.clock() - t0)}
            except ValueError as exc:
                return fail(f"initialisation failed: {exc}")
        try:
            hull = self._hull(cams, images, start)
        except ValueError as exc:  # a malformed image or zone: this frame is lost, the next may do
            return fail(f"hull: {exc}")
        self.last_hull = hull
        t_hull = self.clock()
        if hull.n_voxels < o.min_voxels:
            self.previous = None
            if self._walk is not None:
                self._walk.reset()
            if self._legs is not None:
                self._legs.reset()
            return fail(f"hull in the zone of interest has {hull.n_voxels} voxels < {o.min_voxels}")
        if self.blobs is None:
            self.blobs = learn_blobs(self.model, start, hull.centres, hull.sizes, hull.colours, layout=self.layout,
                                     offset_weight=o.offset_weight, max_offset_m=o.max_offset_m)
        params, quality = self.fit(hull, start)
        joints = joint_centre_array(self.model, forward(self.model, params))
        if self._legs is not None:
            self._legs.add(params)
        why = self.judge(quality)
        record.update(
            ok=not why, params=[float(v) for v in params],
            joints={n: [float(v) for v in joints[i]] for i, n in enumerate(self.model.joint_names)},
            iterations=int(o.em_iterations), voxels=int(hull.n_voxels),
            active_fraction=quality["active_fraction"], unexplained=quality["unexplained"],
            support_min=quality["support_min"], support_min_part=quality["support_min_part"],
            goal_rms_mm=1e3 * quality["goal_rms_m"] if np.isfinite(quality["goal_rms_m"]) else None,
            hull_ms=1e3 * (t_hull - t0),
        )
        if why:
            record["reason"] = "poor fit: " + "; ".join(why)
            self.previous = None
        else:
            self.previous = self.params
        self.params = params
        if self._walk is not None:
            if o.walk_source == "hull":
                w = hull.volumes
                self._walk.add(1e-9 * int(timestamp_ns), (w @ hull.centres[:, :2]) / w.sum(),
                               joints[self._walk.root_joint, 2])
            else:
                self._walk.add_pose(1e-9 * int(timestamp_ns), joints)
        record["latency_ms"] = 1e3 * (self.clock() - t0)
        return record
