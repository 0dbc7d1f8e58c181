"""Retarget BVH motion onto a body model: per-frame inverse kinematics on joint centres.

Steps (``retarget_bvh``):

1. **Axes.** BVH world (Y up) -> contourcap world (Z up) by the proper rotation
   ``(x, y, z)_world = (z, x, y)_bvh``; a subject facing +Z in the BVH faces +X in the world, the
   model's reference heading.  No heading is imposed: the root rotation follows the motion.
2. **Correspondences.** Each model joint centre (``model.joint_names``) is the mean of one or
   more BVH joints, first match in ``JOINT_MAP`` (CMU names and the common ``LeftUpLeg``/``LeftArm``
   style).  For CMU: pelvis = midpoint of LeftHip/RightHip (CMU's ``Hips`` root sits ~9 cm above
   the hip joints), spine = Chest, neck = Neck, head = midpoint of Head and its end site,
   shoulder = LeftShoulder (the humeral head; ``LeftCollar`` is the clavicle), elbow, wrist, hip,
   knee, ankle by name.  The IK matches each to the model's pivot (``BodyModel.pivots``: the hips to
   the thighs' origins, not the reported hip centres inside them).
3. **Size.** Subject height by a least-squares scale fit of the model's segment lengths (at
   height 1) to the BVH's in its rest pose: ``H = Σ L_s r_s / Σ r_s²`` over thigh, shank, upper
   arm, forearm (left and right), shoulder width and pelvis-to-neck.  With ``fit_segments=True``
   the limb segments also get the BVH's own lengths (``segment_lengths``).
4. **Time.** Joint targets are linearly interpolated at ``t_k = start_s +
   k / fps`` from the BVH's frames.
5. **Inverse kinematics.** Per frame, ``scipy.optimize.least_squares``
   (TRF, bounds = joint limits, analytic Jacobian from
   ``tracker.body.kinematics.point_jacobian``) on the residuals
   ``[model joint - target (m)] ⊕ μ·Φ_joints ⊕ μ_t·(Φ - Φ_prev)``; the
   small damping keeps unobservable DOF (twists, the abdomen/torso split)
   near the reference and the motion smooth.  Warm-started frame to frame.
6. **Placement.** The horizontal midpoint of the pelvis' path is moved to
   the origin (``center=True``), and the root height is shifted so that the
   lowest model foot-surface point over the clip touches z = 0; targets get
   the same shifts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
from scipy.optimize import least_squares

from tracker.synthetic.bvh import Bvh, bvh_forward
from tracker.body.kinematics import forward, joint_centre_array, point_jacobian
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel, load_model
from tracker.imaging.render import body_points

__all__ = ["JOINT_MAP", "Retargeted", "retarget_bvh", "palindrome", "bvh_joint_targets", "estimate_size", "BVH_TO_WORLD"]

#: BVH (Y up) -> world (Z up): x_w = z_b, y_w = x_b, z_w = y_b (a proper rotation).
BVH_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

#: model joint -> alternatives, first whose BVH joints all exist wins; a tuple is averaged.
JOINT_MAP: Mapping[str, tuple] = {
    "pelvis": (("LeftHip", "RightHip"), ("LeftUpLeg", "RightUpLeg"), ("Hips",)),
    "spine": (("Chest",), ("Spine1",), ("Spine",)),
    "neck": (("Neck",), ("lowerneck",)),
    "head": (("Head", "Head_End"), ("Head",)),
    "left_shoulder": (("LeftArm",), ("LeftShoulder",)),
    "left_elbow": (("LeftForeArm",), ("LeftElbow",)),
    "left_wrist": (("LeftHand",), ("LeftWrist",)),
    "right_shoulder": (("RightArm",), ("RightShoulder",)),
    "right_elbow": (("RightForeArm",), ("RightElbow",)),
    "right_wrist": (("RightHand",), ("RightWrist",)),
    "left_hip": (("LeftUpLeg",), ("LeftHip",)),
    "left_knee": (("LeftLeg",), ("LeftKnee",)),
    "left_ankle": (("LeftFoot",), ("LeftAnkle",)),
    "right_hip": (("RightUpLeg",), ("RightHip",)),
    "right_knee": (("RightLeg",), ("RightKnee",)),
    "right_ankle": (("RightFoot",), ("RightAnkle",)),
}

# segments for sizing: (name for segment_lengths or None, joint a, joint b)
_SEGMENTS = (
    ("thigh", "left_hip", "left_knee"), ("thigh", "right_hip", "right_knee"),
    ("shank", "left_knee", "left_ankle"), ("shank", "right_knee", "right_ankle"),
    ("upper_arm", "left_shoulder", "left_elbow"), ("upper_arm", "right_shoulder", "right_elbow"),
    ("forearm", "left_elbow", "left_wrist"), ("forearm", "right_elbow", "right_wrist"),
    (None, "left_shoulder", "right_shoulder"), (None, "pelvis", "neck"),
)  # fmt: skip


@dataclass(frozen=True, eq=False)
class Retargeted:
    """Motion on a model.

    Attributes
    ----------
    model : BodyModel
        The sized model the parameters drive.
    params : ndarray, shape (n_frames, n_params)
    targets : ndarray, shape (n_frames, n_joints, 3)
        BVH joint targets in the world frame (metres, Z up), ``joint_names`` order.
    residual_m : ndarray, shape (n_frames, n_joints)
        Distance between the model's joint centres and the targets after IK.
    joint_names : tuple of str, length n_joints
        The model joints with a BVH correspondence (``JOINT_MAP``), in model order:
        the columns of ``targets`` and ``residual_m``.
    times_s : ndarray, shape (n_frames,)
        Time of each frame in the BVH clip.
    fps : float
    height_m : float
    segment_lengths : dict
        Explicit segment lengths given to the model (empty unless ``fit_segments``).
    """

    model: BodyModel
    params: np.ndarray
    targets: np.ndarray
    residual_m: np.ndarray
    times_s: np.ndarray
    fps: float
    height_m: float
    segment_lengths: dict
    joint_names: tuple

    @property
    def n_frames(self) -> int:
        return self.params.shape[0]


def palindrome(motion: Retargeted) -> Retargeted:
    """The motion forward then backward: frames ``0 … n-1, n-2 … 1`` (``2n - 2`` frames).

    Played in a loop it never jumps: after the last frame (motion frame 1) comes frame 0, one
    frame's motion away, as between any two neighbours.  ``times_s`` follow the frames (clip times,
    not increasing).  A motion of fewer than 3 frames is returned as it is.
    """
    n = motion.n_frames
    if n < 3:
        return motion
    idx = np.concatenate([np.arange(n), np.arange(n - 2, 0, -1)])
    return Retargeted(model=motion.model, params=motion.params[idx], targets=motion.targets[idx],
                      residual_m=motion.residual_m[idx], times_s=motion.times_s[idx], fps=motion.fps,
                      height_m=motion.height_m, segment_lengths=dict(motion.segment_lengths),
                      joint_names=motion.joint_names)


def _resolve_map(bvh: Bvh, joint_names) -> list[list[int]]:
    out = []
    for name in joint_names:
        for alt in JOINT_MAP.get(name, ()):
            if all(j in bvh.names for j in alt):
                out.append([bvh.names.index(j) for j in alt])
                break
        else:
            raise ValueError(f"{bvh.source}: no BVH joint for model joint {name!r} (tried {JOINT_MAP.get(name)})")
    return out


def bvh_joint_targets(bvh: Bvh, joint_names, frames=None) -> np.ndarray:
    """Model-joint targets from a BVH in the world frame (Z up, file units).

    Parameters
    ----------
    bvh : Bvh
    joint_names : sequence of str
        Model joint names (``JOINT_MAP``).
    frames : sequence of int, optional
        BVH frames (default all).

    Returns
    -------
    ndarray, shape (n_frames, n_joints, 3)
    """
    P, _ = bvh_forward(bvh, frames)
    idx = _resolve_map(bvh, joint_names)
    T = np.stack([P[:, i].mean(axis=1) for i in idx], axis=1)
    return T @ BVH_TO_WORLD.T


def estimate_size(bvh: Bvh, model_name: str = "knossow40", *, fit_segments: bool = False) -> tuple[float, dict]:
    """Subject height (and optionally limb lengths) from the BVH's rest pose; see the module docstring.

    Parameters
    ----------
    bvh : Bvh
    model_name : str
    fit_segments : bool
        Also the limb segments' own lengths.

    Returns
    -------
    height_m : float
    segment_lengths : dict str -> float
        Metres; empty without ``fit_segments``.
    """
    unit = load_model(model_name, height_m=1.0)
    rest = Bvh(bvh.names, bvh.parent, bvh.offset, bvh.channels, bvh.channel_start,
               np.zeros((1, bvh.motion.shape[1])), bvh.frame_time_s, bvh.source)  # fmt: skip
    names = sorted({j for _, a, b in _SEGMENTS for j in (a, b)})
    T = dict(zip(names, bvh_joint_targets(rest, names)[0]))
    M = dict(zip(names, forward(unit, unit.zero()).to_world(*unit.pivots(names))))
    L = np.array([np.linalg.norm(T[a] - T[b]) for _, a, b in _SEGMENTS])
    r = np.array([np.linalg.norm(M[a] - M[b]) for _, a, b in _SEGMENTS])
    height = float(np.sum(L * r) / np.sum(r * r))
    lengths: dict = {}
    if fit_segments:
        for seg in ("thigh", "shank", "upper_arm", "forearm"):
            lengths[seg] = float(np.mean([l for (s, _, _), l in zip(_SEGMENTS, L) if s == seg]))
    return height, lengths


def _initial_root(model: BodyModel, targets: np.ndarray, names) -> np.ndarray:
    """Root translation and heading from one frame's targets (n_joints, 3) named ``names``."""
    ji = {n: i for i, n in enumerate(names)}
    mi = {n: i for i, n in enumerate(model.joint_names)}
    p = model.zero()
    left = targets[ji["left_hip"]] - targets[ji["right_hip"]]
    yaw = np.arctan2(left[1], left[0]) - np.pi / 2  # the model's left is +Y at Φ = 0
    p[model.param_kind == ROOT_ROTATION] = [0.0, 0.0, yaw]
    pose = forward(model, p)
    pelvis_model = joint_centre_array(model, pose)[mi["pelvis"]]
    p[model.param_kind == ROOT_TRANSLATION] = targets[ji["pelvis"]] - pelvis_model
    return p


def _solve_frame(model, target, start, prev, mu, mu_t, jpart, jpoint):
    """One frame of IK: ``target`` (n, 3) for the model points ``jpoint`` (n, 3) of parts ``jpart``."""
    joint_dof = model.param_kind == JOINT_ROTATION
    lo = np.where(np.isfinite(model.lower), model.lower, -np.inf)
    hi = np.where(np.isfinite(model.upper), model.upper, np.inf)
    n = model.n_params

    cache: dict = {}

    def posed(p):
        key = p.tobytes()
        if key not in cache:
            cache.clear()
            pose = forward(model, p)
            cache[key] = (pose, pose.to_world(jpart, jpoint))
        return cache[key]

    def fun(p):
        r = (posed(p)[1] - target).ravel()
        return np.concatenate([r, mu * p[joint_dof], mu_t * (p - prev)])

    def jac(p):
        pose, X = posed(p)
        J = point_jacobian(model, pose, jpart, X).reshape(-1, n)
        D = np.eye(n)[joint_dof] * mu
        return np.concatenate([J, D, mu_t * np.eye(n)])

    x0 = np.clip(start, lo + 1e-9, hi - 1e-9)
    res = least_squares(fun, x0, jac=jac, bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=60, xtol=1e-8, ftol=1e-9)
    return res.x


def retarget_bvh(
    bvh: Bvh,
    *,
    model: str = "knossow40",
    fps: float = 30.0,
    frames: int | None = None,
    start_s: float = 0.0,
    height_m: float | None = None,
    fit_segments: bool = False,
    center: bool = True,
    damping: float = 0.01,
    smoothing: float = 0.02,
) -> Retargeted:
    """BVH motion -> model parameters per frame (see the module docstring).

    Parameters
    ----------
    fps : float
        Output frame rate; frames are sampled at ``start_s + k / fps``.
    frames : int, optional
        Number of output frames (default: as many as the clip holds).
    height_m : float, optional
        Override the estimated subject height.
    damping, smoothing : float
        μ (metres per radian of joint angle) and μ_t (per unit parameter change
        from the previous frame) of the IK regularisers.

    Returns
    -------
    Retargeted
    """
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"retarget_bvh: fps must be positive, got {fps}")
    duration = (bvh.n_frames - 1) * bvh.frame_time_s
    if not (0.0 <= start_s <= duration):
        raise ValueError(f"retarget_bvh: start_s={start_s} outside the clip (0..{duration:.3f} s) of {bvh.source}")
    available = int(np.floor((duration - start_s) * fps + 1e-9)) + 1
    n_out = available if frames is None else int(frames)
    if not (1 <= n_out <= available):
        raise ValueError(f"retarget_bvh: frames={frames} but {bvh.source} holds {available} frames at {fps} fps from {start_s} s")
    est_h, lengths = estimate_size(bvh, model, fit_segments=fit_segments)
    H = est_h if height_m is None else float(height_m)
    mdl = load_model(model, height_m=H, segment_lengths=lengths or None)
    times = start_s + np.arange(n_out) / fps
    src = times / bvh.frame_time_s
    i0 = np.minimum(np.floor(src).astype(int), bvh.n_frames - 1)
    i1 = np.minimum(i0 + 1, bvh.n_frames - 1)
    w = (src - i0)[:, None, None]
    needed = np.unique(np.concatenate([i0, i1]))
    names = tuple(n for n in mdl.joint_names if n in JOINT_MAP)
    jidx = np.array([mdl.joint_names.index(n) for n in names])
    T_all = bvh_joint_targets(bvh, names, frames=needed)
    pos = {f: k for k, f in enumerate(needed)}
    T = (1 - w) * T_all[[pos[f] for f in i0]] + w * T_all[[pos[f] for f in i1]]
    ji = {n: i for i, n in enumerate(names)}
    if center:
        pel = T[:, ji["pelvis"], :2]
        T[:, :, :2] -= 0.5 * (pel.min(axis=0) + pel.max(axis=0))
    params = np.empty((n_out, mdl.n_params))
    pivots = mdl.pivots(names)
    p = _initial_root(mdl, T[0], names)
    prev = p.copy()
    for k in range(n_out):
        # the first frame has no predecessor to stay close to
        p = _solve_frame(mdl, T[k], p, prev, damping, smoothing if k else 0.0, *pivots)
        params[k] = prev = p
    # floor: the lowest foot-surface point of the clip on z = 0
    feet = [mdl.part_index(n) for n in mdl.part_names if n.endswith("foot") or n.endswith("shank")]
    lowest = min(body_points(mdl, forward(mdl, q))[feet, :, 2].min() for q in params)
    params[:, mdl.param_kind == ROOT_TRANSLATION] -= [0.0, 0.0, lowest]
    T[:, :, 2] -= lowest
    joints = np.stack([joint_centre_array(mdl, forward(mdl, q))[jidx] for q in params])
    return Retargeted(
        model=mdl, params=params, targets=T, residual_m=np.linalg.norm(joints - T, axis=-1),
        times_s=times, fps=float(fps), height_m=H, segment_lengths=dict(lengths), joint_names=names,
    )  # fmt: skip
