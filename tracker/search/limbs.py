"""Limbs exchanged: the pose with the two legs' (or arms') chains swapped, and when to try it.

At mid-stride the silhouettes of the two legs cross, and a frame-to-frame fit can carry the left
thigh onto the right leg's silhouette and the right onto the left's: the body's silhouette is still
explained, so the quality gate passes.  The exchanged hypothesis is the pose with the two chains'
joint angles swapped through the pelvis's sagittal plane (``exchange_limbs``: the DOF map of
``tracker.search.mirror.mirror_map`` applied to one pair of chains only, the root and the trunk
unchanged), so that each leg takes the other's place in the pelvis frame.

The legs can also end *crossed*: after a turn or an exchange the left ankle on the right ankle's side of
the pelvis (``ankle_crossing`` negative), each leg reaching across to the other's silhouette.  The
exchanged hypothesis of a crossed pair is crossed as well; ``leg_candidates``' ``"uncrossed"`` start
is the exchange with both legs' abduction and twist at zero, each foot under its own hip on the other
leg's fore-aft place.

``StrideWatch`` says when to try it: the legs have crossed since the last check (the ankles'
fore-aft separation along the pelvis heading changed sign, each time beyond a dead band), which is
where an exchange happens and after which it shows (the legs apart again, each on the other's
silhouette).  A body that does not stride (standing, hopping, crouching) is never checked.

``exchange_verdict`` weighs the fitted exchanged pose against the pose by
``tracker.search.mirror.hypothesis_cost`` (chamfer RMS, silhouette IoU, joints at their limits: a
knee bent backwards sits at its limit), and says whether the two are one solution, the exchange is
clearly better, or the two are too close to call.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import JOINT_ROTATION, BodyModel
from tracker.search.mirror import exchange_sides, mirror_map, pelvis_heading

__all__ = ["LEGS", "ARMS", "exchange_limbs", "limb_dofs", "side_chains", "leg_candidates", "ankle_separation", "StrideWatch",
           "ExchangeVerdict", "arm_candidates", "ARM_STARTS", "ankle_crossing", "exchange_verdict", "chain_joint_distance", "KEPT", "EXCHANGED", "UNSURE", "SAME"]

#: the chains' part names without their ``left_``/``right_`` prefix
LEGS = ("thigh", "shank", "foot")
ARMS = ("clavicle", "upper_arm", "forearm", "hand")
#: the suffixes of ``arm_candidates``' start names (what tells an arm start from a leg start)
ARM_STARTS = ("hanging", "bent", "raised", "previous")

KEPT, EXCHANGED, UNSURE, SAME = "kept", "exchanged", "unsure", "same"


@lru_cache(maxsize=32)
def _dofs(model: BodyModel, chain: tuple) -> np.ndarray:
    parts = {f"{side}_{p}" for side in ("left", "right") for p in chain}
    k = [i for i, n in enumerate(model.param_names)
         if model.param_kind[i] == JOINT_ROTATION and n.split(".")[0] in parts]
    out = np.array(k, dtype=int)
    out.setflags(write=False)
    return out


def limb_dofs(model: BodyModel, chain: tuple = LEGS) -> np.ndarray:
    """Indices of the joint DOF of both sides' ``chain`` parts, shape (k,) (empty when the model has none)."""
    return _dofs(model, tuple(chain))


def exchange_limbs(model: BodyModel, params: np.ndarray, chain: tuple = LEGS) -> np.ndarray:
    """``params`` with the left and right ``chain`` (``LEGS`` or ``ARMS``) exchanged.

    Each side's joint angles go to the other side with the signs of ``mirror_map``: in the frame of
    the chain's parent (the pelvis for the legs, the thorax for the arms) the left chain then lies
    where the right one lay reflected in the sagittal plane, and vice versa.  The root, the trunk and
    the other chains are unchanged; applying it twice gives ``params``.

    Parameters
    ----------
    model : BodyModel
    params : ndarray, shape (n_params,)
    chain : tuple of str

    Returns
    -------
    ndarray, shape (n_params,)
    """
    return exchange_sides(model, params, np.asarray(limb_dofs(model, chain), dtype=int))


def leg_candidates(model: BodyModel, params: np.ndarray, crossed: bool = False) -> list[tuple[str, np.ndarray]]:
    """The starts a leg check fits besides the pose: the legs exchanged (``exchange_limbs``) and each
    leg alone put straight (its DOF zero: hanging from the hip, the start for a leg that followed the
    other leg's silhouette) and, with ``crossed``, the exchange with both legs' abduction and twist at zero
    (module docstring).  List of (name, params), names ``"exchanged"``, ``"left_straight"``,
    ``"right_straight"`` and ``"uncrossed"``."""
    p = np.asarray(params, dtype=float)
    exchanged = exchange_limbs(model, p, LEGS)
    out = [("exchanged", model.clamp(exchanged))]
    if crossed:
        q = exchanged.copy()
        q[[k for k in limb_dofs(model, LEGS) if model.param_names[k].split(".")[-1] in ("abduction", "twist")]] = 0.0
        out.append(("uncrossed", model.clamp(q)))
    legs = dict(side_chains(model))
    for side in ("left", "right"):
        q = p.copy()
        q[legs.get(f"{side} leg", np.zeros(0, dtype=int))] = 0.0
        out.append((f"{side}_straight", model.clamp(q)))
    return out


@lru_cache(maxsize=32)
def _hanging(model: BodyModel) -> tuple[int, float]:
    """(index, value) of the left upper arm's abduction DOF that brings the T-pose arm down beside the
    trunk: 80° towards the side that lowers the wrist (a relaxed arm hangs a little away from the
    trunk, the hand beside the thigh)."""
    k = model.param_names.index("left_upper_arm.abduction")
    names = list(model.joint_names)
    w, s = names.index("left_wrist"), names.index("left_shoulder")
    best = None
    for v in (model.lower[k], model.upper[k]):
        p = np.zeros(model.n_params)
        p[k] = np.clip(v, -np.radians(80.0), np.radians(80.0))
        j = joint_centre_array(model, forward(model, p))
        drop = j[s, 2] - j[w, 2]
        if best is None or drop > best[1]:
            best = (float(p[k]), drop)
    return k, best[0]


def arm_candidates(model: BodyModel, params: np.ndarray, previous: np.ndarray | None = None
                   ) -> list[tuple[str, np.ndarray]]:
    """The starts an arm check fits besides the pose, each moving one arm alone (its DOF only): hanging
    along the trunk (its DOF zero but the upper arm's abduction, lowered by 80°), hanging with the elbow
    bent a right angle (the forearm forward, the hand before the belly), raised (every DOF zero: the
    arm held out sideways) and, with ``previous`` (a pose of an earlier good frame), in that pose.
    List of (name, params), names ``"{side}_hanging"``, ``"{side}_bent"``, ``"{side}_raised"``,
    ``"{side}_previous"`` (``ARM_STARTS``), left then right."""
    p = np.asarray(params, dtype=float)
    index, sign = mirror_map(model)
    k, down = _hanging(model)
    out = []
    arms = dict(side_chains(model))
    names = list(model.param_names)
    for side in ("left", "right"):
        dofs = arms.get(f"{side} arm", np.zeros(0, dtype=int))
        raised = p.copy()
        raised[dofs] = 0.0
        q = raised.copy()
        q[k if side == "left" else index[k]] = down if side == "left" else sign[k] * down
        out.append((f"{side}_hanging", model.clamp(q)))
        elbow = f"{side}_forearm.flexion"
        if elbow in names:
            b = q.copy()
            b[names.index(elbow)] = np.pi / 2
            out.append((f"{side}_bent", model.clamp(b)))
        out.append((f"{side}_raised", model.clamp(raised)))
        if previous is not None:
            q = p.copy()
            q[dofs] = np.asarray(previous, dtype=float)[dofs]
            out.append((f"{side}_previous", model.clamp(q)))
    return out


def side_chains(model: BodyModel) -> list[tuple[str, np.ndarray]]:
    """Each side's arm and leg: ``[(name, joint DOF indices), ...]`` ("left arm", "right arm", "left leg",
    "right leg"; a chain the model has no DOF for is left out)."""
    out = []
    for chain, label in ((ARMS, "arm"), (LEGS, "leg")):
        for side in ("left", "right"):
            dofs = np.array([i for i in limb_dofs(model, chain) if model.param_names[i].startswith(side + "_")],
                            dtype=int)
            if dofs.size:
                out.append((f"{side} {label}", dofs))
    return out


def ankle_separation(model: BodyModel, params: np.ndarray, pose=None) -> float:
    """Left ankle minus right ankle along the pelvis heading (``pelvis_heading``), metres; NaN when
    the model has no ankles or the pelvis faces up or down.  ``pose``: ``forward(model, params)`` if
    already computed."""
    names = list(model.joint_names)
    if "left_ankle" not in names or "right_ankle" not in names:
        return float("nan")
    h = pelvis_heading(model, params)
    if not np.any(h):
        return float("nan")
    j = joint_centre_array(model, forward(model, params) if pose is None else pose)
    d = j[names.index("left_ankle")] - j[names.index("right_ankle")]
    return float(d[:2] @ h)


def ankle_crossing(model: BodyModel, params: np.ndarray, pose=None) -> float:
    """Left ankle minus right ankle along the pelvis's left axis (its hip line in the horizontal
    plane), metres: negative when the legs are crossed; NaN when the model has no ankles or hips.
    ``pose``: ``forward(model, params)`` if already computed."""
    names = list(model.joint_names)
    want = ("left_ankle", "right_ankle", "left_hip", "right_hip")
    if not all(n in names for n in want):
        return float("nan")
    j = joint_centre_array(model, forward(model, params) if pose is None else pose)
    la, ra, lh, rh = (j[names.index(n)] for n in want)
    side = (lh - rh)[:2]
    norm = float(np.linalg.norm(side))
    if norm < 1e-9:
        return float("nan")
    return float((la - ra)[:2] @ side / norm)


class StrideWatch:
    """Whether the legs crossed since the last check.

    Parameters
    ----------
    dead_band_m : float
        An ankle separation (``ankle_separation``) counts only beyond ±this, metres.
    """

    def __init__(self, dead_band_m: float) -> None:
        if not (np.isfinite(dead_band_m) and dead_band_m > 0):
            raise ValueError(f"dead_band_m: expected a positive distance, got {dead_band_m}")
        self.dead_band_m = float(dead_band_m)
        self.reset()

    def reset(self) -> None:
        """Forget the last side (a re-initialisation, a turn)."""
        self.side = 0

    def update(self, separation_m: float) -> bool:
        """Add a frame's separation; true when it is beyond the dead band on the other side from the
        last one that was (the legs crossed)."""
        if not np.isfinite(separation_m) or abs(separation_m) <= self.dead_band_m:
            return False
        side = 1 if separation_m > 0 else -1
        crossed = self.side != 0 and side != self.side
        self.side = side
        return crossed


@dataclass(frozen=True)
class ExchangeVerdict:
    """``exchange_verdict``'s answer: ``choice`` (``KEPT``, ``EXCHANGED``, ``UNSURE`` or ``SAME``),
    ``cost_kept``, ``cost_exchanged`` (``hypothesis_cost`` units) and ``apart_m`` (the largest
    distance between the two fits' joints of the chain, metres)."""

    choice: str
    cost_kept: float
    cost_exchanged: float
    apart_m: float


def exchange_verdict(cost_kept: float, cost_exchanged: float, apart_m: float, *, margin: float,
                     same_m: float) -> ExchangeVerdict:
    """Which of a pose and its fitted exchanged hypothesis to keep.

    ``SAME`` when the chain's joints of the two fits are within ``same_m`` metres (the exchanged start
    converged back: there is one solution); else ``EXCHANGED`` when its cost is lower by more than
    ``margin``, ``UNSURE`` when it is lower by less (the exchange explains the images as well: the frame
    is not to be trusted), ``KEPT`` otherwise.  A non-finite exchanged cost is ``KEPT``.
    """
    if not np.isfinite(cost_exchanged):
        choice = KEPT
    elif apart_m <= same_m:
        choice = SAME
    elif not np.isfinite(cost_kept) or cost_exchanged < cost_kept - margin:
        choice = EXCHANGED
    elif cost_exchanged < cost_kept:
        choice = UNSURE
    else:
        choice = KEPT
    return ExchangeVerdict(choice, float(cost_kept), float(cost_exchanged), float(apart_m))


def chain_joint_distance(model: BodyModel, pose_a, pose_b, chain: tuple = LEGS) -> float:
    """Largest distance between the joints of both sides' ``chain`` (knees and ankles for ``LEGS``,
    elbows and wrists for ``ARMS``) in two poses, metres."""
    want = ("knee", "ankle") if tuple(chain) == LEGS else ("elbow", "wrist")
    idx = [i for i, n in enumerate(model.joint_names) if n.split("_", 1)[-1] in want]
    a, b = joint_centre_array(model, pose_a)[idx], joint_centre_array(model, pose_b)[idx]
    return float(np.max(np.linalg.norm(a - b, axis=1))) if idx else 0.0
