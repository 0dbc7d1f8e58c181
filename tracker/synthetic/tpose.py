"""T-pose-start sessions of a subject who is not the tracking model, and the mirrored-frame count.

A subject's segment lengths are drawn ±``spread`` around the model's (``subject_model``); the
subject stands in a T-pose at a random place and heading, holds it, lowers the arms with straight
legs (the silhouettes still cannot tell front from back), then blends into a bundled CMU clip
turned to that heading (``tpose_start_motion``).  ``tpose_subject`` gives the motion and the colours
for ``service.synthetic_session.make_synthetic_session`` (the session's ``[subject]`` then holds the
height only, so the tracker's model keeps its own proportions), with a head whose back is hair
and a shirt whose back differs from its front (``sided_palette``).

``mirrored_frames`` counts the tracked frames turned round (``tracker.synthetic.evaluation``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from capture.camera import matrix_to_rodrigues
from tracker.body.kinematics import forward, so3_exp
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, ROOT_TRANSLATION, BodyModel, load_model
from tracker.imaging.render import body_points
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.retarget import Retargeted, retarget_bvh
from tracker.synthetic.scene import make_room_texture
from tracker.synthetic.synth import Palette, bundled_motion, make_palette

__all__ = ["subject_model", "tpose_start_motion", "sided_palette", "tpose_subject", "mirrored_frames", "mean_error_m"]


def subject_model(rng: np.random.Generator, *, name: str = "knossow40", height_m: float = 1.75,
                  spread: float = 0.15) -> BodyModel:
    """``name`` at ``height_m`` with every named segment's length (``BodyModel.segments``: both
    sides alike) drawn uniformly within ±``spread`` (fraction) of the model's own."""
    if not 0.0 <= spread < 0.5:
        raise ValueError(f"spread: expected in [0, 0.5), got {spread}")
    base = load_model(name, height_m=height_m)
    lengths = {}
    for seg, part in sorted(base.segments.items()):
        nominal = float(base.cones[part, 4])  # z2: the segment's length along its axis
        lengths[seg] = nominal * float(rng.uniform(1.0 - spread, 1.0 + spread))
    return load_model(name, height_m=height_m, segment_lengths=lengths)


def _lowest(model: BodyModel, params: np.ndarray) -> float:
    return float(body_points(model, forward(model, params), n_theta=12, n_z=3)[..., 2].min())


def _smoothstep(n: int) -> np.ndarray:
    s = (np.arange(n) + 1.0) / (n + 1.0)
    return s * s * (3.0 - 2.0 * s)


def tpose_start_motion(subject: BodyModel, rng: np.random.Generator, *, fps: float = 30.0, hold_s: float = 1.0,
                       lower_s: float = 0.5, blend_s: float = 0.5, move_s: float = 1.0, clip: str = "scaled_131_03",
                       clip_start_s: float = 0.0, place_m: float = 0.5) -> Retargeted:
    """Motion of ``subject``: a T-pose at a random place (±``place_m``) and heading held ``hold_s``,
    the arms lowered to 60° below horizontal over ``lower_s`` (legs straight), a ``blend_s`` blend
    into the bundled ``clip`` (turned and moved to start there) and ``move_s`` of it.

    Returns a ``Retargeted`` on ``subject`` (``segment_lengths`` empty: a session written from it
    holds the height only); ``targets`` and ``residual_m`` are empty.
    """
    n_hold, n_lower, n_blend, n_move = (int(round(s * fps)) for s in (hold_s, lower_s, blend_s, move_s))
    if n_hold < 1 or min(n_lower, n_blend, n_move) < 0:
        raise ValueError("tpose_start_motion: hold_s must give at least one frame, the others >= 0")
    t_idx = np.flatnonzero(subject.param_kind == ROOT_TRANSLATION)
    r_idx = np.flatnonzero(subject.param_kind == ROOT_ROTATION)
    joints = subject.param_kind == JOINT_ROTATION
    heading = float(rng.uniform(-np.pi, np.pi))
    place = rng.uniform(-place_m, place_m, 2)
    tpose = subject.zero()
    tpose[r_idx] = [0.0, 0.0, heading]
    tpose[t_idx] = [place[0], place[1], 0.0]
    tpose[t_idx[2]] -= _lowest(subject, tpose)
    lowered = tpose.copy()
    arms = [subject.param_index(f"{s}_upper_arm.abduction") for s in ("left", "right")]
    lowered[arms] = np.radians(-60.0)
    frames = [tpose] * n_hold + [tpose + a * (lowered - tpose) for a in _smoothstep(n_lower)]
    if n_blend + n_move > 0:
        motion = retarget_bvh(load_bvh(bundled_motion(clip)), fps=fps, frames=max(n_move, 1), start_s=clip_start_s)
        clip_p = motion.params.copy()
        # turn the clip about the vertical through its first pelvis to the subject's heading, move it there
        R0 = so3_exp(clip_p[0, r_idx])
        turn = heading - float(np.arctan2(R0[1, 0], R0[0, 0]))
        Rz = so3_exp(np.array([0.0, 0.0, turn]))
        first = clip_p[0, t_idx].copy()
        for k in range(len(clip_p)):
            clip_p[k, t_idx] = Rz @ (clip_p[k, t_idx] - first) + [place[0], place[1], 0.0]
            clip_p[k, r_idx] = matrix_to_rodrigues(Rz @ so3_exp(clip_p[k, r_idx]))
        # the subject's legs are not the clip model's: one floor offset for the whole clip
        clip_p[:, t_idx[2]] -= min(_lowest(subject, q) for q in clip_p)
        target = clip_p[0]
        last = frames[-1]
        for a in _smoothstep(n_blend):
            q = last.copy()
            q[joints] = last[joints] + a * (target[joints] - last[joints])
            q[t_idx] = last[t_idx] + a * (target[t_idx] - last[t_idx])
            q[r_idx] = matrix_to_rodrigues(so3_exp(last[r_idx]) @ so3_exp(
                a * _rotvec(so3_exp(last[r_idx]).T @ so3_exp(target[r_idx]))))
            frames.append(q)
        frames += list(clip_p[:n_move])
    params = subject.clamp(np.array(frames))
    n = len(params)
    return Retargeted(model=subject, params=params, targets=np.zeros((n, 0, 3)), residual_m=np.zeros((n, 0)),
                      times_s=np.arange(n) / fps, fps=float(fps), height_m=float(subject.height_m),
                      segment_lengths={}, joint_names=())


def _rotvec(R: np.ndarray) -> np.ndarray:
    return np.asarray(matrix_to_rodrigues(R), dtype=float)


def sided_palette(model: BodyModel, rng: np.random.Generator) -> Palette:
    """``make_palette`` with a back side: hair on the back of the head, and a shirt whose back
    is another colour than its front (a print, a different garment)."""
    base = make_palette(model, rng)
    back = base.colours.copy()
    hair = np.array([[25.0, 30.0, 40.0], [30.0, 60.0, 110.0], [90.0, 150.0, 190.0], [40.0, 40.0, 45.0]])
    shirt_back = rng.uniform(30, 220, 3)
    for i, name in enumerate(model.part_names):
        if name == "head":
            back[i] = hair[rng.integers(len(hair))]
        elif name in ("torso", "abdomen"):
            back[i] = shirt_back
    return Palette(base.colours, base.light, back)


def tpose_subject(seed: int, *, spread: float = 0.15, sided: bool = True, shoes: str = "dark",
                  **motion) -> tuple[Retargeted, Palette]:
    """The motion (``tpose_start_motion``, keyword arguments ``motion``) and colours of a
    ``subject_model`` drawn from ``seed``, for ``service.synthetic_session.make_synthetic_session``
    (``retargeted=``, ``palette=``; its ground truth then holds the subject's joints).

    ``sided``: ``sided_palette`` (else ``make_palette``); ``shoes``: ``"dark"`` (the palette's) or
    ``"shadow"`` (the floor's colour at half its brightness for a room of the same ``seed``: what
    a segmentation takes for the body's shadow, so the feet are missing from the silhouettes).
    """
    if shoes not in ("dark", "shadow"):
        raise ValueError(f"shoes: expected 'dark' or 'shadow', got {shoes!r}")
    rng = np.random.default_rng(seed)
    subject = subject_model(rng, spread=spread)
    moving = tpose_start_motion(subject, rng, **motion)
    palette = (sided_palette if sided else make_palette)(subject, np.random.default_rng(seed + 1))
    if shoes == "shadow":
        floor = make_room_texture(seed, extent_m=1.0, wall_radius_m=1.5).floor.reshape(-1, 3).mean(axis=0)
        feet = [i for i, n in enumerate(subject.part_names) if n.endswith("foot")]
        colours = palette.colours.copy()
        back = None if palette.back is None else palette.back.copy()
        for arr in (colours, back):
            if arr is not None:
                arr[feet] = 0.5 * floor
        palette = Palette(colours, palette.light, back)
    return moving, palette


# ----------------------------------------------------------------------------- counting
def mirrored_frames(records: Sequence[Mapping], truth: Sequence[Mapping]) -> list[int]:
    """Frame ids of the pose ``records`` (with ``joints``) that are mirrored against the ground-truth
    records ``truth`` (indexed by frame id): ``tracker.synthetic.evaluation.mirrored_frames`` (the limbs
    clearly nearer the left/right-swapped or the front/back-reflected truth)."""
    from tracker.synthetic.evaluation import frame_errors
    from tracker.synthetic.evaluation import mirrored_frames as mirrored
    from tracker.synthetic.people import JOINT_NAMES

    posed = [r for r in records if "joints" in r]
    if not posed:
        return []
    pred = np.array([[r["joints"][n] for n in JOINT_NAMES] for r in posed], dtype=float)
    true = np.array([[truth[r["frame"]]["joints"][n] for n in JOINT_NAMES] for r in posed], dtype=float)
    flags = mirrored(frame_errors(pred, true))
    return [int(r["frame"]) for r, f in zip(posed, flags) if f]


def mean_error_m(record: Mapping, truth: Mapping) -> float:
    """Mean joint distance (metres) of a pose record's ``joints`` to a ground-truth record's."""
    names = [n for n in truth["joints"] if n in record["joints"]]
    return float(np.mean([np.linalg.norm(np.subtract(record["joints"][n], truth["joints"][n])) for n in names]))
