"""Scores of a tracked clip against ground-truth joint centres (``bench/robustness.py``).

Arrays hold the 16 contourcap joints in ``JOINT_NAMES`` order, world metres.  A frame without a
pose (the tracker gave no joints) is a row of NaN in the prediction.

Per frame:

- **error**: the mean joint distance (MPJPE) to the truth;
- **mirrored**: the prediction is closer to a swapped truth than to the truth, clearly:
  ``min(e_lr, e_fb) < MIRROR_RATIO · e`` and ``e − min(e_lr, e_fb) > MIRROR_MARGIN_M``, where
  ``e``, ``e_lr`` and ``e_fb`` are the mean errors over the 12 limb joints (shoulders to ankles:
  the trunk joints do not move under a swap) to the truth, to the truth with every ``left_`` and
  ``right_`` name exchanged (left/right swapped: what a track turned round by 180° fits onto a
  symmetric pose), and to the truth reflected front to back through its coronal plane (the
  vertical plane through the pelvis along the hip line);
- **false ok**: reported ok with an error above ``FALSE_OK_M``; **false alarm**: reported not ok
  with a pose whose error is below ``FALSE_ALARM_M``;
- **PCK**: joints within ``PCK_M`` of the truth (a frame without a pose counts every joint as
  missed).
"""

from __future__ import annotations

import numpy as np

from tracker.synthetic.people import JOINT_NAMES

__all__ = ["LIMB_JOINTS", "swap_left_right", "reflect_front_back", "frame_errors", "mirrored_frames",
           "score_clip", "summarise_clips", "FALSE_OK_M", "FALSE_ALARM_M", "PCK_M", "MIRROR_RATIO",
           "MIRROR_MARGIN_M"]

FALSE_OK_M = 0.080
FALSE_ALARM_M = 0.040
PCK_M = 0.050
MIRROR_RATIO = 0.6
MIRROR_MARGIN_M = 0.030

#: indices of the limb joints (shoulders, elbows, wrists, hips, knees, ankles)
LIMB_JOINTS = np.array([i for i, n in enumerate(JOINT_NAMES) if n.startswith(("left_", "right_"))])
_SWAP = np.array([JOINT_NAMES.index(n.replace("left_", "@").replace("right_", "left_").replace("@", "right_"))
                  for n in JOINT_NAMES])  # fmt: skip
_PELVIS, _LHIP, _RHIP = (JOINT_NAMES.index(n) for n in ("pelvis", "left_hip", "right_hip"))


def _check(joints: np.ndarray, name: str) -> np.ndarray:
    j = np.asarray(joints, dtype=float)
    if j.ndim != 3 or j.shape[1:] != (len(JOINT_NAMES), 3):
        raise ValueError(f"{name}: expected shape (n_frames, {len(JOINT_NAMES)}, 3), got {j.shape}")
    return j


def swap_left_right(joints: np.ndarray) -> np.ndarray:
    """Joints (n, 16, 3) with every ``left_`` and ``right_`` joint exchanged."""
    return _check(joints, "joints")[:, _SWAP]


def reflect_front_back(joints: np.ndarray) -> np.ndarray:
    """Joints (n, 16, 3) reflected through each frame's coronal plane: the vertical plane through
    the pelvis containing the horizontal direction of the hip line (names kept)."""
    j = _check(joints, "joints")
    side = j[:, _LHIP] - j[:, _RHIP]
    fwd = np.stack([-side[:, 1], side[:, 0], np.zeros(len(j))], axis=1)
    fwd /= np.maximum(np.linalg.norm(fwd, axis=1, keepdims=True), 1e-12)
    off = np.sum((j - j[:, _PELVIS : _PELVIS + 1]) * fwd[:, None], axis=2)
    return j - 2.0 * off[..., None] * fwd[:, None]


def frame_errors(pred: np.ndarray, truth: np.ndarray) -> dict:
    """Per-frame errors (metres) of ``pred`` against ``truth``, both (n, 16, 3).

    Returns a dict of arrays of shape (n,) (NaN where ``pred`` has no pose): ``mpjpe`` (all
    joints), ``limbs`` (limb joints), ``limbs_lr`` (limbs against the left/right-swapped truth),
    ``limbs_fb`` (limbs against the front/back-reflected truth); and ``joint`` (n, 16).
    """
    p, t = _check(pred, "pred"), _check(truth, "truth")
    if p.shape != t.shape:
        raise ValueError(f"pred {p.shape} and truth {t.shape} differ in shape")
    joint = np.linalg.norm(p - t, axis=2)
    lr = np.linalg.norm(p - swap_left_right(t), axis=2)
    fb = np.linalg.norm(p - reflect_front_back(t), axis=2)
    return {"joint": joint, "mpjpe": joint.mean(axis=1), "limbs": joint[:, LIMB_JOINTS].mean(axis=1),
            "limbs_lr": lr[:, LIMB_JOINTS].mean(axis=1), "limbs_fb": fb[:, LIMB_JOINTS].mean(axis=1)}


def mirrored_frames(errors: dict) -> np.ndarray:
    """Bool (n,): frames whose prediction is clearly closer to a swapped truth (module docstring)."""
    e, alt = errors["limbs"], np.minimum(errors["limbs_lr"], errors["limbs_fb"])
    with np.errstate(invalid="ignore"):
        return (alt < MIRROR_RATIO * e) & (e - alt > MIRROR_MARGIN_M)


def score_clip(pred: np.ndarray, ok, truth: np.ndarray, *, fps: float, skip_s: float = 1.0) -> dict:
    """Counts and means of one clip.

    Parameters
    ----------
    pred, truth : ndarray, shape (n, 16, 3)
        Predicted (NaN rows: no pose) and true joints, metres.
    ok : array-like of bool, shape (n,)
        The tracker's ``ok`` flags.
    fps : float
    skip_s : float
        Frames before this time are left out of ``mirrored_after``.

    Returns
    -------
    dict
        ``frames``, ``posed`` (frames with a pose), ``ok``, ``false_ok``, ``false_alarm``,
        ``mirrored`` (all frames), ``mirrored_after`` and ``frames_after`` (from ``skip_s``),
        ``pck_hits`` (joints within ``PCK_M``), ``error_sum_m`` (sum of per-frame MPJPE over posed
        frames), ``mpjpe_mm`` (their mean, None without any), ``mpjpe_ok_mm`` (over ok frames).
    """
    err = frame_errors(pred, truth)
    ok = np.asarray(ok, dtype=bool)
    n = len(ok)
    if err["mpjpe"].shape != (n,):
        raise ValueError(f"ok has {n} frames, pred {err['mpjpe'].shape[0]}")
    posed = np.isfinite(err["mpjpe"])
    e = np.where(posed, err["mpjpe"], np.inf)
    mir = mirrored_frames(err) & posed
    after = np.arange(n) >= int(round(skip_s * fps))
    mm = lambda sel: float(1e3 * err["mpjpe"][sel].mean()) if np.any(sel) else None  # noqa: E731
    return {
        "frames": n, "posed": int(posed.sum()), "ok": int(ok.sum()),
        "false_ok": int(np.sum(ok & (e > FALSE_OK_M))), "false_alarm": int(np.sum(~ok & posed & (e < FALSE_ALARM_M))),
        "mirrored": int(mir.sum()), "mirrored_after": int(np.sum(mir & after)), "frames_after": int(after.sum()),
        "pck_hits": int(np.sum(np.where(posed[:, None], err["joint"], np.inf) < PCK_M)),
        "error_sum_m": float(err["mpjpe"][posed].sum()), "mpjpe_mm": mm(posed), "mpjpe_ok_mm": mm(posed & ok),
    }  # fmt: skip


def summarise_clips(clips: list[dict]) -> dict:
    """Totals over clips scored by ``score_clip``: percentages of all frames (PCK: of all joints),
    MPJPE pooled over posed frames and the worst clip's."""
    if not clips:
        raise ValueError("no clips to summarise")
    tot = {k: sum(c[k] for c in clips) for k in ("frames", "posed", "ok", "false_ok", "false_alarm", "mirrored",
                                                   "mirrored_after", "frames_after", "pck_hits")}
    pct = lambda a, b: 100.0 * a / b if b else None  # noqa: E731
    per = [c["mpjpe_mm"] for c in clips if c["mpjpe_mm"] is not None]
    return {
        "mpjpe_mm_mean": 1e3 * sum(c["error_sum_m"] for c in clips) / tot["posed"] if tot["posed"] else None,
        "mpjpe_mm_worst_clip": max(per) if per else None,
        "pck50_percent": pct(tot["pck_hits"], tot["frames"] * len(JOINT_NAMES)),
        "mirrored_frames_percent": pct(tot["mirrored_after"], tot["frames_after"]),
        "mirrored_frames_percent_including_first_second": pct(tot["mirrored"], tot["frames"]),
        "ok_percent": pct(tot["ok"], tot["frames"]),
        "false_ok_percent": pct(tot["false_ok"], tot["frames"]),
        "false_alarm_percent": pct(tot["false_alarm"], tot["frames"]),
        "no_pose_percent": pct(tot["frames"] - tot["posed"], tot["frames"]),
        "frames": tot["frames"],
    }
