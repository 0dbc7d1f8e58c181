"""Offline temporal smoothing of a take's pose records (``contourcap track``; live poses are never smoothed).

``smoothed_records`` smooths a stream of pose records in frame order (``service.offline.settled_records``) as
:func:`tracker.body.window.smooth_poses` does: each posed frame's pose becomes the model's nearest to the centred-window
mean of its neighbours' joint centres, started from the window mean of their ``params`` (root position, root
rotation, joint angles), and its ``joints`` are recomputed from it by forward kinematics, so bone lengths and
joint limits hold.  The window never crosses a break (``pose_breaks``): a frame
without a pose, a gap in frame ids, a change of model or of the reported front/back hypothesis, or a joint that
moves faster than ``max_speed_mps`` between two frames (a search, a recovery, a front/back or limb switch).
A record whose pose changed gets ``"smoothed": true``; its verdict and quality figures (``ok``, ``reason``,
``iou``, ``rms_px``...) stay its fit's.  The stream is held ``half`` records behind its input (the window's
look-ahead); when the input ends or raises (an interrupt) the records held are yielded first, smoothed with the
frames there are.
"""

from __future__ import annotations

from typing import Iterable, Iterator

import numpy as np

from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import BodyModel
from tracker.body.window import fit_joints, segment_halves, smooth_params, window_mean

__all__ = ["SMOOTH_WINDOW_S", "MAX_JOINT_SPEED_MPS", "window_half", "pose_breaks", "smoothed_records"]

#: ``contourcap track``'s default window length, seconds (5 frames at 30 fps)
SMOOTH_WINDOW_S = 1.0 / 6.0
#: a joint moving faster than this between two frames (metres per second) breaks the window
MAX_JOINT_SPEED_MPS = 16.0


def window_half(window_s: float, fps: float) -> int:
    """The half-width in frames of a centred window ``window_s`` seconds long at ``fps`` frames per second
    (the window is 2·half + 1 frames, the odd count nearest ``window_s · fps``)."""
    if not (window_s >= 0 and fps > 0):
        raise ValueError(f"smoothing window: expected window_s >= 0 and fps > 0, got {window_s}, {fps}")
    return max(0, int(np.floor((window_s * fps - 1.0) / 2.0 + 0.5)))


def _posed(rec: dict, model: BodyModel) -> bool:
    p, joints = rec.get("params"), rec.get("joints")
    return (p is not None and len(p) == model.n_params and rec.get("model", model.name) == model.name
            and isinstance(joints, dict) and all(n in joints for n in model.joint_names)
            and bool(np.all(np.isfinite(p))))


def _joint_array(records: list[dict], posed, model: BodyModel) -> np.ndarray:
    """The records' joint centres in ``model.joint_names`` order, zeros for a record not ``posed``;
    shape (len(records), n_joints, 3), metres."""
    return np.array([[r["joints"][n] for n in model.joint_names] if p else np.zeros((len(model.joint_names), 3))
                     for r, p in zip(records, posed)], float)


def pose_breaks(records: list[dict], model: BodyModel, *, fps: float,
                max_speed_mps: float = MAX_JOINT_SPEED_MPS) -> np.ndarray:
    """Where a window may not reach across: True for a record that starts a new segment.

    Parameters
    ----------
    records : list of dict, pose records in frame order
    model : BodyModel, the records' model
    fps : float, frames per second (the joint step limit is ``max_speed_mps / fps`` metres per frame step)
    max_speed_mps : float, metres per second

    Returns
    -------
    ndarray of bool, shape (len(records),): the first record, a record without a pose or after one, after a gap
    in frame ids, or whose model, reported front/back hypothesis or any joint (beyond the step limit) changed.
    """
    n = len(records)
    if n == 0:
        return np.zeros(0, bool)
    posed = np.array([_posed(r, model) for r in records])
    J = _joint_array(records, posed, model)
    frames = np.array([r["frame"] for r in records])
    hyp = [r.get("front_back_reported") for r in records]
    same = np.array([a == b for a, b in zip(hyp[:-1], hyp[1:])], bool)
    step = np.sqrt(((J[1:] - J[:-1]) ** 2).sum(axis=2)).max(axis=1)
    joined = posed[1:] & posed[:-1] & (np.diff(frames) == 1) & same & (step <= max_speed_mps / fps)
    return np.append(True, ~joined)


def _smooth_window(window: list[dict], model: BodyModel, *, half: int, fps: float, max_speed_mps: float,
                   at: int) -> dict:
    """``window[at]`` smoothed over ``window`` (the records about it; ``smooth_poses`` for that row alone)."""
    rec = window[at]
    if half == 0 or not _posed(rec, model):
        return rec
    breaks = pose_breaks(window, model, fps=fps, max_speed_mps=max_speed_mps)
    h = segment_halves(breaks, half)
    if h[at] == 0:
        return rec
    posed = [_posed(r, model) for r in window]
    P = np.array([r["params"] if p else model.zero() for r, p in zip(window, posed)], float)
    J = _joint_array(window, posed, model)
    start = smooth_params(model, P, half=half, breaks=breaks)[at]
    row = fit_joints(model, start[None], window_mean(J, h)[at][None])[0]
    joints = joint_centre_array(model, forward(model, row))
    return {**rec, "params": [float(v) for v in row],
            "joints": {n: [float(v) for v in joints[i]] for i, n in enumerate(model.joint_names)}, "smoothed": True}


def smoothed_records(records: Iterable[dict], model: BodyModel, *, half: int, fps: float,
                     max_speed_mps: float = MAX_JOINT_SPEED_MPS) -> Iterator[dict]:
    """``records`` (pose records in frame order) with their poses smoothed over a centred window (module docstring).

    Parameters
    ----------
    records : iterable of dict, pose records in frame order
    model : BodyModel, the model whose ``params`` the records hold
    half : int, ≥ 0, the window's half-width in frames (``window_half``; 0: the records unchanged)
    fps : float, the take's frames per second (the joint step limit of ``pose_breaks``)
    max_speed_mps : float, ``pose_breaks``' joint speed limit, metres per second

    Yields
    ------
    dict
        Each record, in the same order, at most ``half`` records after it arrived.
    """
    if half < 0:
        raise ValueError(f"smoothing: expected half >= 0, got {half}")
    past: list[dict] = []     # up to ``half`` records already yielded (their fitted poses)
    pending: list[dict] = []  # records waiting for their look-ahead

    def emit(final: bool) -> Iterator[dict]:
        while pending and (final or len(pending) > half):
            window = past + pending[:half + 1]
            out = _smooth_window(window, model, half=half, fps=fps, max_speed_mps=max_speed_mps, at=len(past))
            past.append(pending.pop(0))
            if len(past) > half:  # keep the last ``half`` (none when half is 0)
                del past[:len(past) - half]
            yield out

    try:
        for rec in records:
            pending.append(rec)
            yield from emit(False)
    except (Exception, KeyboardInterrupt):
        yield from emit(True)
        raise
    yield from emit(True)
