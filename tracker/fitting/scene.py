"""Tracking in a real scene: decide which foreground is body before fitting it.

``SceneTracker`` wraps ``tracker.fitting.tracking.Tracker`` with the segmentation of every frame
and the clutter of ``segmentation.clutter``:

1. each camera's frame is segmented with the clutter cut out (operator ignore regions and the
   learned static clutter), except where the body's projection at the last fit covers it;
2. the tracker fits the frame set on those silhouettes; the gate (RMS, inside fraction, IoU)
   judges the fit against them;
3. a *trusted* fit (RMS and inside fraction within the tracker's limits, and a share of the
   foreground left unexplained no larger than ``max_unexplained``) feeds the static-clutter
   learner: foreground the body does not cover that stays unchanged for ``learn_frames`` frames
   becomes clutter.  A fit that put a limb on a prop leaves the real limb unexplained; the
   bound on the unexplained share keeps such a fit from teaching the learner;
4. while no clutter is learned yet (the first ``warmup_frames`` frames after an
   initialisation), the reverse (silhouette → model) term is off: it would pull the nearest limb
   onto the outline of a prop; the model → image terms alone keep a good start where it is;
   recovery searches wait too, and later keep to a CPU budget (``recovery_gap``,
   ``recovery_share``);
5. the first pose is searched standing (T/A-pose) and seated (``tracker.search.seated``);
   an offline caller may fit the warm-up's frames again, backwards from the settled state
   (``retrack``: the reverse term on, the clutter learned and the props cut);
6. operator props (``tracker.fitting.props``: world boxes such as the chair) are cut where the
   body's grown projection does not cover them (optionally also where a pixel's ray enters a prop
   before it meets the body: ``SceneOptions.prop_depth_tol_m``), and the fit may not put the body
   inside them.

The bound on the unexplained share is the only guard against a wrong fit teaching the learner
the real body as clutter; a fit that starts on the prop and stays there can learn the person.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, replace
from typing import Mapping, Sequence

import cv2
import numpy as np

from segmentation.background import BackgroundModel
from segmentation.clutter import StaticClutter, segment_without_clutter
from segmentation.pipeline import SegmentationParams
from tracker.body.kinematics import forward, joint_centres
from tracker.fitting.props import PropBox, PropPenalty, prop_masks, prop_rays, rays_meet_capsules, seat_box
from tracker.fitting.tracking import Tracker, refit_options
from tracker.search.scoring import ScoreViews
from tracker.search.seated import initialise_any

__all__ = ["RecoveryBudget", "SceneOptions", "SceneTracker"]


@dataclass(frozen=True)
class SceneOptions:
    """Options of :class:`SceneTracker`.

    learn : learn static clutter (False: only the ignore regions are cut)
    learn_frames : frames a pixel must be static, unexplained foreground to become clutter
    colour_tol : ``StaticClutter.colour_tol``
    margin_m : the body's projection is grown by this much (metres at the body's depth) before it
        counts as explained, so its outline's pixels are never learned
    max_unexplained : a fit leaving more than this share of the foreground unexplained does not
        feed the learner
    warmup_frames : frames after an initialisation with the reverse term off and no recovery
    recovery_gap, recovery_share : the CPU budget of recovery (a search costs tens of frames'
        fits): at least ``recovery_gap`` frames between two searches, and a search only while the
        cost of the searches is at most ``recovery_share`` of the cost of tracking
    recovery_cost_frames : a search is charged as this many frames' fits, a frame as one, so that
        the budget (and so the poses) do not depend on the machine's speed or load (None: both
        charged their measured seconds)
    seated : the first pose is searched standing (T/A) and seated (``tracker.search.seated``)
    heights : subject heights (metres) the seated search also tries, the tracker's model re-sized
        to the best (None: only the model's own; a seated subject's height is not on the hull)
    """

    learn: bool = True
    learn_frames: int = 25
    colour_tol: float = 40.0
    margin_m: float = 0.04
    max_unexplained: float = 0.45
    warmup_frames: int = 25
    recovery_gap: int = 25
    recovery_share: float = 0.2
    recovery_cost_frames: float | None = 40.0
    seated: bool = True
    heights: tuple | None = None
    #: ``PropPenalty``'s weight (pixels per metre of intrusion) and clearance (× a part's radius)
    prop_weight: float = 2000.0
    prop_clearance: float = 1.0
    #: the thighs' clearance from ``PropPenalty``'s root (pelvis) factor at the hip to
    #: ``prop_clearance`` at the knee (``PropPenalty.thigh_taper``)
    prop_thigh_taper: bool = False
    #: a prop's pixels are body where the body's projection grown by this covers them (metres;
    #: None: ``margin_m``, as learned clutter)
    prop_margin_m: float | None = None
    #: a prop's pixel kept as body (within the grown projection) only where its ray, before it
    #: enters a solid prop (the whole ray through a hollow one: a chair's outline is seen through),
    #: passes within a part's radius grown by this (metres) of the part's axis
    #: (None, the default: no ray test, the grown projection alone decides; off by default: with the
    #: chair's parts the knees come forward but the hips and the rendered scenes' ok do not follow:
    #: docs/real_floor.md)
    prop_depth_tol_m: float | None = None
    #: without operator props, learn the seat of a subject fitted seated on the first frame
    #: (``tracker.fitting.props.seat_box``) and use it as a prop (off by default: docs/real_floor.md)
    auto_seat: bool = False


class RecoveryBudget:
    """When a recovery search may run: ``SceneOptions``' ``recovery_gap``, ``recovery_share`` and
    ``recovery_cost_frames`` (None: costs in measured seconds)."""

    def __init__(self, gap: int, share: float, cost_frames: float | None) -> None:
        self.gap, self.share, self.cost_frames = int(gap), float(share), cost_frames
        self.since = self.gap  # frames since the last search or initialisation
        self.tracking = 0.0    # cost of every frame's step (searches included)
        self.searching = 0.0   # cost of the searches

    def allows(self) -> bool:
        """Whether a search may run on the next frame."""
        return self.since >= self.gap and self.searching <= self.share * self.tracking

    def frame(self, seconds: float, *, searched: bool, restart: bool) -> None:
        """Charge one frame's step that took ``seconds``; ``searched``: it ran a search (charged as
        one); ``restart``: a search or an initialisation ran (the gap starts again)."""
        fixed = self.cost_frames is not None
        self.tracking += 1.0 if fixed else float(seconds)
        if searched:
            self.searching += float(self.cost_frames) if fixed else float(seconds)
        self.since = 0 if restart else self.since + 1


class SceneTracker:
    """Segment, cut clutter, fit, learn; one pose record per frame set.

    Parameters
    ----------
    tracker : Tracker (its cameras are the studio's)
    backgrounds : camera name -> BackgroundModel
    ignore : camera name -> (h, w) bool mask of the operator's ignore regions (optional)
    options : SceneOptions
    segmentation : SegmentationParams for every camera
    floor : segmentation.floor.FloorShadows or None, the multi-view floor test of shadow-like pixels
    props : sequence of ``tracker.fitting.props.PropBox``, the operator's props (optional)

    Attributes
    ----------
    learners : camera name -> StaticClutter (empty when ``options.learn`` is False)
    last_segmentation : camera name -> FrameSegmentation of the last frame (the body's silhouettes)
    warming : the last frame was fitted in the warm-up (reverse term off, no recovery)
    """

    def __init__(self, tracker: Tracker, backgrounds: Mapping[str, BackgroundModel], *,
                 ignore: Mapping[str, np.ndarray] | None = None, options: SceneOptions = SceneOptions(),
                 segmentation: SegmentationParams | None = None, floor=None,
                 props: "list[PropBox] | None" = None) -> None:
        self.tracker = tracker
        self.options = options
        self.props: list[PropBox] = []
        self.prop_masks: dict[str, np.ndarray] = {}
        self.learned_seat: PropBox | None = None
        self._seat_tried = bool(props) or not options.auto_seat
        self.set_props(list(props or ()))
        self.floor = floor
        self.backgrounds = dict(backgrounds)
        self.segmentation = segmentation or SegmentationParams()
        self.ignore = {n: np.asarray(m, dtype=bool) for n, m in (ignore or {}).items()}
        for n, m in self.ignore.items():
            cam = tracker.cameras.get(n)
            if cam is None:
                raise ValueError(f"ignore: unknown camera {n!r}")
            if m.shape != (cam.height, cam.width):
                raise ValueError(f"ignore[{n!r}]: shape {m.shape} != (h, w) = {(cam.height, cam.width)}")
        self.learners = ({n: StaticClutter((c.width, c.height), learn_frames=options.learn_frames,
                                           colour_tol=options.colour_tol) for n, c in tracker.cameras.items()}
                         if options.learn else {})
        self._views = self._render_views()
        self._base_options = tracker.options
        self._since_init = 0
        self.budget = RecoveryBudget(options.recovery_gap, options.recovery_share, options.recovery_cost_frames)
        self._recover = tracker.recover
        self._inits = tracker.n_initialisations
        self._explained: dict[str, np.ndarray] = {}
        self._prop_keep: dict[str, np.ndarray] = {}  # with prop_margin_m: the body's projection so grown
        self.last_segmentation: dict = {}
        self.warming = False

    def set_props(self, props: "list[PropBox]") -> None:
        """Use ``props`` from the next frame on (their masks and the fit's limit)."""
        self.props = list(props)
        self.prop_masks = prop_masks(self.tracker.cameras.values(), self.props) if self.props else {}
        self.prop_rays = (prop_rays(self.tracker.cameras.values(), self.props, self.prop_masks)
                          if self.props and self.options.prop_depth_tol_m is not None else {})
        self.tracker.penalty = (PropPenalty(self.props, weight=self.options.prop_weight,
                                            clearance=self.options.prop_clearance,
                                            thigh_taper=self.options.prop_thigh_taper) if self.props else None)

    def _learn_seat(self, params: np.ndarray, raws: Mapping[str, np.ndarray]) -> None:
        """``SceneOptions.auto_seat``: once, from the first fit, the seat under a seated subject."""
        self._seat_tried = True
        jc = joint_centres(self.tracker.model, forward(self.tracker.model, params))
        names = [n for n in self.tracker.cameras if n in raws]
        if len(names) < 2:
            return
        model = self.tracker.model
        thighs = [i for i, name in enumerate(model.part_names) if name.endswith("thigh")]
        radius = float(np.max(model.cones[thighs, :2])) if thighs else 0.0
        box = seat_box([self.tracker.cameras[n] for n in names], {n: raws[n] > 0 for n in names},
                       self._explained, jc, thigh_radius=radius)
        if box is not None:
            self.learned_seat = box
            self.set_props([box])

    def _render_views(self) -> ScoreViews:
        cams = list(self.tracker.cameras.values())
        return ScoreViews(self.tracker.model, cams, [np.zeros((c.height, c.width), np.uint8) for c in cams], scale=0.5)

    def clutter(self, name: str) -> np.ndarray | None:
        """Camera ``name``'s clutter (h, w) bool: learned, and the props' projection once there is a
        fit (the start search sees them: cut without a body to keep, they would cut it); or None
        (the ignore regions are apart: ``ignore``)."""
        learner = self.learners.get(name)
        learned = None if learner is None else learner.mask
        prop = self.prop_masks.get(name) if name in self._explained else None
        if prop is None or self._prop_cut_apart():
            return learned
        return prop if learned is None else (learned | prop)

    def _prop_cut_apart(self) -> bool:
        """Whether the props' pixels are cut by the ignore path (``prop_margin_m`` or
        ``prop_depth_tol_m`` set) rather than as clutter."""
        return self.options.prop_margin_m is not None or self.options.prop_depth_tol_m is not None

    def _ignore(self, name: str) -> np.ndarray | None:
        """The pixels cut whatever the body covers: the operator's ignore regions, and with
        ``prop_margin_m`` or ``prop_depth_tol_m`` the props' pixels not kept as body."""
        ignore = self.ignore.get(name)
        keep = self._prop_keep.get(name)
        if keep is None:
            return ignore
        prop = self.prop_masks[name] & ~keep
        return prop if ignore is None else (ignore | prop)

    def explained(self, params: np.ndarray, margin_m: float | None = None) -> dict[str, np.ndarray]:
        """The body's projection at ``params`` per camera, (h, w) bool, grown by ``margin_m``
        (None: ``SceneOptions.margin_m``)."""
        margin_m = self.options.margin_m if margin_m is None else float(margin_m)
        out = {}
        pelvis = np.asarray(params[:3], dtype=float)
        for small, (name, cam) in zip(self._views.render(np.asarray(params, dtype=float)),
                                       self.tracker.cameras.items()):
            full = cv2.resize(small.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
            depth = max(float(cam.depth(pelvis[None])[0]), 0.3)
            r = int(np.ceil(margin_m * cam.matrix[0, 0] / depth))
            if r > 0:
                full = cv2.dilate(full, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
            out[name] = full.astype(bool)
        return out

    def prop_keep(self, params: np.ndarray) -> dict[str, np.ndarray]:
        """Per camera, (h, w) bool: the pixels where a prop's projection is kept as body at
        ``params``: the body's projection grown by ``prop_margin_m`` (None: ``margin_m``), and with
        ``prop_depth_tol_m`` a prop pixel only where its ray, before it enters a solid prop (the whole
        ray when it passes hollow ones only), passes within a part's radius grown by
        ``prop_depth_tol_m`` of the part's axis (``body_capsules``; ``props.rays_meet_capsules``): a
        ray that meets a solid prop first shows the prop, one through a hollow prop that meets no body
        shows what is behind it.  Pixels whose ray meets no prop are kept as by the projection alone."""
        margin = self.options.margin_m if self.options.prop_margin_m is None else self.options.prop_margin_m
        keep = self.explained(params, margin)
        tol = self.options.prop_depth_tol_m
        if tol is None:
            return keep
        a, b, radius = self.body_capsules(params)
        for name, rays in self.prop_rays.items():
            v, u = rays.pixels[:, 0], rays.pixels[:, 1]
            sel = np.flatnonzero(keep[name][v, u] & rays.through)
            if not sel.size:
                continue
            meets = rays_meet_capsules(rays.origin, rays.directions[sel], rays.entry[sel], a, b, radius + float(tol))
            keep[name][v[sel[~meets]], u[sel[~meets]]] = False
        return keep

    def body_capsules(self, params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every part as a capsule along its axis at ``params``: the axis' ends (n_parts, 3) and
        (n_parts, 3), world metres, and radii (n_parts,), the larger semi-axis of the part's cone at
        its wider end."""
        model = self.tracker.model
        pose = forward(model, np.asarray(params, dtype=float))
        a, b, k, z1, z2 = (model.cones[:, i] for i in range(5))
        parts = np.arange(model.n_parts)
        ends = [pose.to_world(parts, np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)) for z in (z1, z2)]
        r = np.maximum(a, b) * np.maximum(np.maximum(1.0 + k * z1, 1.0 + k * z2), 0.0)
        return ends[0], ends[1], r

    def step(self, frame_id: int, timestamp_ns: int, images: Mapping[str, np.ndarray]) -> dict:
        """Segment ``images`` (camera name -> BGR uint8 (h, w, 3)), fit, learn; the pose record."""
        segs, raws = {}, {}
        for name, img in images.items():
            segs[name], raws[name] = segment_without_clutter(
                self.backgrounds[name], img, self.clutter(name), keep=self._explained.get(name),
                ignore=self._ignore(name), params=self.segmentation,
                floor=None if self.floor is None else self.floor.for_camera(name, images))
        self.last_segmentation = segs
        tr = self.tracker
        if tr.params is None and self.options.seated:
            self._initialise(segs)
        inits = tr.n_initialisations  # after this class's own start search (not a recovery)
        warm = self._since_init < self.options.warmup_frames and self.options.learn
        self.warming = warm
        tr.options = replace(self._base_options, reverse_weight=0.0) if warm else self._base_options
        tr.recover = self._recover and not warm and self.budget.allows()
        t0 = time.perf_counter()
        rec = tr.step(frame_id, timestamp_ns, {n: s.chamfer for n, s in segs.items()},
                      silhouettes={n: s.silhouette for n, s in segs.items()}, images=images)
        tr.options, tr.recover = self._base_options, self._recover
        dt = time.perf_counter() - t0
        restart = tr.n_initialisations != self._inits
        self.budget.frame(dt, searched=tr.n_initialisations != inits, restart=restart)
        if restart:
            self._inits, self._since_init = tr.n_initialisations, 0
        else:
            self._since_init += 1
        if "params" not in rec:
            self._explained, self._prop_keep = {}, {}
            return rec
        params = np.asarray(rec["params"], dtype=float)
        self._explained = self.explained(params)
        if not self._seat_tried:
            self._learn_seat(params, raws)
        if self.props and self._prop_cut_apart():
            self._prop_keep = self.prop_keep(params)
        if self.learners and self._trusted(rec):
            fg = {n: raws[n] > 0 for n in images}
            n_fg = sum(int(np.count_nonzero(m)) for m in fg.values())
            n_out = sum(int(np.count_nonzero(fg[n] & ~self._explained[n])) for n in images)
            if n_fg and n_out <= self.options.max_unexplained * n_fg:
                for n, img in images.items():
                    self.learners[n].update(img, raws[n], self._explained[n])
        return rec

    def retrack(self, frames: Sequence[tuple[int, int, Mapping[str, np.ndarray]]]) -> list[dict]:
        """Fit ``frames`` again, in the order given, from this tracker's state, on a copy (this
        tracker is left as it is); their pose records in that order.

        ``frames``: ``(frame id, timestamp ns, camera name -> BGR image)``, usually the warm-up's
        frames latest first, so that each fit starts from its successor's: the copy fits them with
        the reverse term on (its warm-up is over), the clutter learned so far, the props cut where
        the body does not cover them, no velocity into the first of them, and the IoU checked on every
        frame (``tracker.fitting.tracking.refit_options``).  The background models, which nothing changes, are
        shared with the copy."""
        twin = copy.deepcopy(self, {id(bg): bg for bg in self.backgrounds.values()})
        twin._since_init = max(twin._since_init, self.options.warmup_frames)
        twin.tracker.previous = None
        twin._base_options = refit_options(twin._base_options)
        return [twin.step(fid, ts, images) for fid, ts, images in frames]

    def _initialise(self, segs: Mapping) -> None:
        """The first pose: standing or seated search on the frame's silhouettes (nothing learned
        yet); leaves the tracker uninitialised when the search fails (it then tries its own)."""
        tr = self.tracker
        names = [n for n in tr.cameras if n in segs and np.any(segs[n].silhouette)]
        if not names:
            return
        heights = [] if self.options.heights is None else list(self.options.heights)
        try:
            res, model = initialise_any(tr.model, [tr.cameras[n] for n in names],
                                        {n: segs[n].silhouette for n in names}, {n: segs[n].chamfer for n in names},
                                        heights=heights)
        except ValueError:
            return
        if model is not tr.model:
            tr.resize(model)  # the front/back guard follows the body too
            self._views = self._render_views()
        tr.params = tr.model.clamp(np.asarray(res.params, dtype=float))
        tr.n_initialisations += 1

    def trusted(self, rec: dict) -> bool:
        """Whether the fit of pose record ``rec`` is one the clutter learner would learn from."""
        return self._trusted(rec)

    def _trusted(self, rec: dict) -> bool:
        """The fit's model → image figures are within the tracker's limits (the IoU may not be:
        it counts the clutter still to learn)."""
        rms, inside = rec.get("rms_px"), rec.get("inside_fraction")
        return (rms is not None and inside is not None and rms <= self.tracker.rms_limit()
                and inside >= self.tracker.options.min_inside_fraction)
