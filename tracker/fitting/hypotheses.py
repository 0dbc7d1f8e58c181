"""Front or back: the tracker keeps a pose and its mirror until the evidence separates them.

Silhouettes cannot tell a T-pose from the same body turned round with left and right exchanged
(``tracker.search.mirror``).  ``FrontBackGuard`` is the tracker's bookkeeping of that question:

* **ambiguous** (from the first frame, after every re-initialisation, and whenever the evidence
  turns against the pose): the mirror hypothesis is tracked beside the pose, each fitted from its
  own previous fit, and every frame adds to an evidence sum ``D`` (positive: the pose, negative:
  the mirror) the clipped per-frame cues

  - ``fit``: the mirror's ``tracker.search.mirror.hypothesis_cost`` (RMS chamfer residual, silhouette
    IoU, joints at their limits — knees and elbows that would have to bend the wrong way) minus
    the pose's;
  - ``feet``: the silhouettes ahead of the ankles (where the pelvis faces) against behind them
    (``tracker.search.appearance.feet_forward``: the feet point forward);
  - ``head``: ``tracker.search.appearance.head_cue`` (face against back of the head, with the frame's
    colour images);
  - ``colour``: the learned ``tracker.search.appearance.AppearanceModel``'s preference for the pose's
    labelling of the image colours over the mirrored one;
  - ``walk``: the pelvis moving at walking speed along the heading rather than against it.

  The frames are reported not ok ("front/back ambiguous"), each with the hypothesis ``D`` favours so
  far (the track goes on from the pose), until ``|D|`` reaches ``margin``; the winner is then kept
  (the tracker switches to the mirror's fit when it wins) and the colour model learned from it.
* **resolved**: every ``check_every`` frames the mirror of the pose is fitted and weighed with the
  same cues, and in between the feet cue and the learned colours against their mirrored labelling; the
  evidence against the pose runs in a leaky sum, and when it reaches ``-reopen`` the question is
  opened again (the frames are reported not ok while the mirror is tracked beside the pose).

The guard never fits anything itself: the tracker passes a ``fit(start, prediction)`` callable.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from tracker.body.model import ROOT_TRANSLATION, BodyModel
from tracker.search.appearance import AppearanceModel, feet_forward, head_cue, surface_colours
from tracker.search.mirror import front_back_cost, joints_at_limits, mirror_params, pelvis_heading

__all__ = ["FrontBackOptions", "FrontBackGuard", "GuardOutcome", "AMBIGUOUS", "RESOLVED"]

AMBIGUOUS, RESOLVED = "ambiguous", "resolved"


@dataclass(frozen=True)
class FrontBackOptions:
    """Weights (per frame, in units of the evidence sum) and thresholds of ``FrontBackGuard``.

    Attributes
    ----------
    margin, min_frames : |evidence| that settles the question, and the frames it takes at least
    fit_weight, fit_clip : per unit of ``hypothesis_cost`` difference, clipped to ±``fit_clip``
    feet_weight : per unit of (occupancy ahead − behind) of ``feet_forward`` (range ±1)
    head_weight, head_scale : ``head_weight`` × clip(``head_cue`` / ``head_scale``, ±1)
    colour_weight, colour_scale : likewise for the learned colour model's ``evidence``
    walk_weight, walk_speed_mps, walk_window : ``walk_weight`` × cos(velocity, heading) when the
        pelvis moved faster than ``walk_speed_mps`` over the last ``walk_window`` frames
    decay, reopen, suspect : the resolved state's leaky sum ``S ← min(0, decay S + cues)`` (on
        frames with cues) re-opens the question at ``-reopen``; frames with ``S`` at or below
        ``-suspect`` are not ok
    check_every, check_iterations : frames between the resolved state's full comparisons (the
        mirror fitted with up to ``check_iterations`` LM steps: the mirror of a contorted pose is
        itself contorted), and the LM steps
    colour_every, learn_every : frames between the resolved state's colour checks (the learned
        colours against their mirrored labelling), and colour checks between colour-model updates
    feet_every : frames between the resolved state's feet checks
    """

    margin: float = 2.0
    min_frames: int = 1
    fit_weight: float = 1.0
    fit_clip: float = 1.0
    feet_weight: float = 2.0
    head_weight: float = 1.0
    head_scale: float = 3.0
    colour_weight: float = 1.0
    colour_scale: float = 1.0
    walk_weight: float = 0.3
    walk_speed_mps: float = 0.4
    walk_window: int = 8
    decay: float = 0.9
    reopen: float = 2.5
    suspect: float = 1.0
    check_every: int = 60
    check_iterations: int = 24
    colour_every: int = 4
    learn_every: int = 3
    feet_every: int = 1


@dataclass
class GuardOutcome:
    """What the guard concluded for a frame: ``swap`` (the mirror's ``(res, terms)`` to track and
    report instead of the pose's, or None), ``reason`` ("" or why the frame is not ok), ``cues`` (the
    frame's evidence terms, for logs and tests), ``report`` (while the question is open and the
    evidence so far favours the mirror: the mirror's ``(res, terms, iou)`` to report for this frame, ``iou``
    its mean silhouette IoU or None, the track going on from the pose; else None)."""

    swap: tuple | None
    reason: str
    cues: dict
    report: tuple | None = None


class FrontBackGuard:
    """See the module docstring.

    Parameters
    ----------
    model : BodyModel
    options : FrontBackOptions

    Attributes
    ----------
    state : ``"ambiguous"`` or ``"resolved"``
    evidence : the evidence sum (ambiguous: positive for the pose; resolved: the leaky sum against it)
    appearance : the learned ``AppearanceModel``
    n_resolved, n_swapped, n_reopened : questions settled, settled for the mirror, re-opened
    """

    def __init__(self, model: BodyModel, options: FrontBackOptions = FrontBackOptions()) -> None:
        self.model = model
        self.options = options
        self.appearance = AppearanceModel(model)
        self.reset()

    def resize(self, model: BodyModel) -> None:
        """Go on with ``model`` (the same parts, other sizes); the colours learned per part are kept."""
        self.model = self.appearance.model = self._pending.model = model

    def offer_mirror(self, params) -> None:
        """The search's own refined mirror of the pose it found (``InitResult.mirror``; None: none), the start
        of the mirror's first fit while the question is open and no mirror is tracked yet: both hypotheses
        are then weighed as far refined (else the searched pose, refined to convergence, is weighed against
        a mirror fitted once)."""
        if self.state == AMBIGUOUS and self.mirror is None:
            self._offered = None if params is None else np.asarray(params, dtype=float)

    def reset(self) -> None:
        """Open the question (first frame, re-initialisation): the mirror is tracked again."""
        self.state = AMBIGUOUS
        self.evidence = 0.0
        self.frames = 0
        self.mirror = None  # (params, previous params) of the mirror hypothesis
        self._offered = None  # a search's refined mirror of the pose (offer_mirror), for the first comparison
        self._pending = AppearanceModel(self.model)  # colours under the pose while ambiguous
        self._pelvis: list[tuple[float, np.ndarray]] = []
        self._since_learn = 0
        self._since_colour = 0
        self._since_check = 0
        self._since_feet = 0
        self.n_resolved = getattr(self, "n_resolved", 0)
        self.n_swapped = getattr(self, "n_swapped", 0)
        self.n_reopened = getattr(self, "n_reopened", 0)

    # ------------------------------------------------------------------ cues
    def _walk(self, params: np.ndarray, t_s: float) -> float:
        o = self.options
        t_idx = np.flatnonzero(self.model.param_kind == ROOT_TRANSLATION)
        self._pelvis = (self._pelvis + [(t_s, np.asarray(params)[t_idx][:2].copy())])[-o.walk_window:]
        if len(self._pelvis) < o.walk_window:
            return 0.0
        (t0, p0), (t1, p1) = self._pelvis[0], self._pelvis[-1]
        if not t1 > t0:
            return 0.0
        v = (p1 - p0) / (t1 - t0)
        speed = float(np.linalg.norm(v))
        if speed < o.walk_speed_mps:
            return 0.0
        return float(o.walk_weight * (pelvis_heading(self.model, params) @ (v / speed)))

    def _feet(self, params, cams, chs, pose=None) -> float:
        """``feet_weight`` × (occupancy ahead of the ankles − behind them), 0 when unclear
        (``tracker.search.appearance.feet_forward``; the mirror faces the other way: its cue is about
        the negative)."""
        ahead, behind = feet_forward(self.model, params, cams, chs, pose=pose)
        return self.options.feet_weight * float(ahead - behind) if np.isfinite(ahead) and np.isfinite(behind) else 0.0

    # ------------------------------------------------------------------ step
    def update(self, *, t_s: float, cams: Sequence, chs: Sequence, images: Sequence | None, res, terms, ok: bool,
               fit: Callable, iou: Callable | None) -> GuardOutcome:
        """One frame: ``res``/``terms`` the pose's fit (SolverResult, CostTerms); ``ok`` whether the
        frame is good otherwise; ``fit(start, prediction) -> (res, terms)`` fits another start;
        ``iou(params) -> float`` the mean silhouette IoU (None: not available)."""
        if self.state == RESOLVED:
            return self._watch(t_s, cams, chs, images, res, terms, ok, fit, iou)
        return self._ambiguous(t_s, cams, chs, images, res, terms, fit, iou)

    def _compare(self, t_s, cams, chs, images, p, terms, pm, terms_m, iou) -> tuple[dict, object, float | None]:
        """The cues of the pose ``p`` against the fitted mirror ``pm`` (positive: the pose), the
        pose's colour samples (None without images) and the mirror's mean IoU (None without ``iou``)."""
        o, model = self.options, self.model
        iou_p = iou(p) if iou is not None else 1.0
        iou_m = iou(pm) if iou is not None else 1.0
        cost_p = front_back_cost(terms.rms_px(), iou_p, joints_at_limits(model, p))
        cost_m = front_back_cost(terms_m.rms_px(), iou_m, joints_at_limits(model, pm))
        cues = {"fit": o.fit_weight * float(np.clip(np.nan_to_num(cost_m - cost_p), -o.fit_clip, o.fit_clip))}
        cues["feet"] = 0.5 * (self._feet(p, cams, chs) - self._feet(pm, cams, chs))
        s = None
        if images is not None:
            s = surface_colours(model, p, cams, images, chs)
            sm = surface_colours(model, pm, cams, images, chs)
            cues["head"] = 0.5 * o.head_weight * float(
                np.clip(head_cue(model, s) / o.head_scale, -1, 1) - np.clip(head_cue(model, sm) / o.head_scale, -1, 1))
            if self.appearance.learned:  # each labelling against the colours learned when the pose was right
                cues["colour"] = 0.5 * o.colour_weight * float(np.clip(
                    (self.appearance.evidence(s) - self.appearance.evidence(sm)) / o.colour_scale, -1.0, 1.0))
        cues["walk"] = self._walk(p, t_s)  # the mirror faces the other way: its cue is the negative
        return cues, s, (float(iou_m) if iou is not None else None)

    def _ambiguous(self, t_s, cams, chs, images, res, terms, fit, iou) -> GuardOutcome:
        o, model = self.options, self.model
        p = np.asarray(res.params, dtype=float)
        if self.mirror is None:
            offered, self._offered = self._offered, None
            start = prev = model.clamp(mirror_params(model, p) if offered is None else offered)
        else:
            cur, prev = self.mirror
            start = model.clamp(2.0 * cur - prev) if prev is not None else cur
        res_m, terms_m = fit(start, self.mirror[0] if self.mirror is not None else start)
        pm = np.asarray(res_m.params, dtype=float)
        self.mirror = (pm, None if self.mirror is None else self.mirror[0])
        cues, s, iou_m = self._compare(t_s, cams, chs, images, p, terms, pm, terms_m, iou)
        if s is not None:
            self._pending.update(s)
        self.evidence += float(sum(cues.values()))
        self.frames += 1
        cues["sum"] = self.evidence
        if self.frames >= o.min_frames and abs(self.evidence) >= o.margin:
            self.state = RESOLVED
            self.n_resolved += 1
            swap = None
            if self.evidence < 0:
                swap = (res_m, terms_m)
                self.n_swapped += 1
                self._pending = self._pending.mirrored()
            if not self.appearance.learned:
                self.appearance = self._pending
            self.mirror = None
            self.evidence = 0.0
            self._since_learn = self._since_colour = self._since_check = 0
            return GuardOutcome(swap, "", cues)
        # not settled: the frame is reported with the hypothesis the evidence favours so far (the
        # pose on a tie), its best estimate; which one is tracked changes only when the margin is reached
        return GuardOutcome(None, f"front/back ambiguous (evidence {self.evidence:+.1f} of ±{o.margin:g})", cues,
                            report=(res_m, terms_m, iou_m) if self.evidence < 0 else None)

    def _watch(self, t_s, cams, chs, images, res, terms, ok, fit, iou) -> GuardOutcome:
        o, model = self.options, self.model
        p = np.asarray(res.params, dtype=float)
        cues: dict = {}
        self._since_check += 1
        self._since_colour += 1
        s = None
        if self._since_check >= o.check_every:  # the mirror fitted and weighed as while ambiguous
            self._since_check = self._since_colour = 0
            start = model.clamp(mirror_params(model, p))
            res_m, terms_m = fit(start, start, o.check_iterations)
            cues, s, _ = self._compare(t_s, cams, chs, images, p, terms, np.asarray(res_m.params, float), terms_m, iou)
        else:
            self._walk(p, t_s)
            self._since_feet += 1
            if self._since_feet >= o.feet_every:
                self._since_feet = 0
                cues["feet"] = self._feet(p, cams, chs, getattr(terms, "pose", None))
            if images is not None and self.appearance.learned and self._since_colour >= o.colour_every:
                self._since_colour = 0
                s = surface_colours(model, p, cams, images, chs)
                cues["colour"] = o.colour_weight * float(np.clip(self.appearance.evidence(s) / o.colour_scale,
                                                                 -1.0, 1.0))
        if s is not None:
            self._since_learn += 1
            if ok and self._since_learn >= o.learn_every and self.appearance.evidence(s) >= 0.0:
                self._since_learn = 0
                self.appearance.update(s)
        # only evidence against the pose accumulates: a resolved pose needs no more support
        if cues:  # decays per evaluation, not per frame
            self.evidence = min(0.0, o.decay * self.evidence + float(sum(cues.values())))
        cues["sum"] = self.evidence
        if self.evidence <= -o.reopen:
            self.n_reopened += 1
            walk = self._pelvis
            self.reset()
            self._pelvis = walk
            out = self._ambiguous(t_s, cams, chs, images, res, terms, fit, iou)
            out.cues["reopened"] = True
            return out
        if self.evidence <= -o.suspect:
            return GuardOutcome(None, f"front/back suspect (evidence {self.evidence:+.1f}, re-opened at "
                                      f"-{o.reopen:g})", cues)
        return GuardOutcome(None, "", cues)
