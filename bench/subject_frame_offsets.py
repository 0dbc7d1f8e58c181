"""Per-joint mean offset of the tracked joints from a reference, in the subject's own frame.

    python bench/subject_frame_offsets.py REFERENCE.jsonl POSES.jsonl

``REFERENCE.jsonl`` is ``bench/real_reference.py``'s ``reference.jsonl`` (or any pose records with
``joints``); ``POSES.jsonl`` is ``contourcap track``'s output.  Per frame the offset (ours minus the
reference) is expressed in the reference's pelvis heading frame: ``side`` along the horizontal
right-hip -> left-hip direction, ``fwd`` = side x up (the way the subject faces), ``up`` = world +z.
The means over the frames tell a systematic lean or twist (e.g. the neck behind, one shoulder
forward) from scatter.  Prints JSON (millimetres) with ``machine_ref_ms``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from machine_ref import machine_ref_ms  # noqa: E402
from real_reference import read_jsonl  # noqa: E402


def heading_frames(left_hip: np.ndarray, right_hip: np.ndarray) -> np.ndarray:
    """Rows (side, fwd, up) of the pelvis heading frames from the hip joints (..., 3), shape (..., 3, 3)."""
    side = np.asarray(left_hip, float) - np.asarray(right_hip, float)
    side[..., 2] = 0.0
    side /= np.maximum(np.linalg.norm(side, axis=-1, keepdims=True), 1e-9)
    up = np.broadcast_to([0.0, 0.0, 1.0], side.shape)
    return np.stack([side, np.cross(side, up), up], axis=-2)


def heading_frame(left_hip: np.ndarray, right_hip: np.ndarray) -> np.ndarray:
    """Rows (side, fwd, up) of the pelvis heading frame from the hip joints, shape (3, 3)."""
    return heading_frames(left_hip, right_hip)


#: a joint's error above this (m) counts as a stretch of the joint lost, not scatter (``decompose``)
LOST_M = 0.15


def decompose(pred: np.ndarray, truth: np.ndarray, names) -> dict:
    """Per-joint error of ``pred`` against ``truth`` (both (n, J, 3), m; NaN rows without a pose) taken
    apart in the truth's pelvis heading frame (side, fwd, up; ``names`` holds ``left_hip`` and
    ``right_hip``), over the posed frames.

    Returns ``{"joints": {name: {error, offset_side, offset_fwd, offset_up, offset, rest, lost}},
    "torso": {...}, "frames": n_posed}`` in mm and degrees: ``offset*`` is the mean error vector (a
    constant offset, i.e. two joint definitions that differ), ``rest`` the mean distance of the error
    from it (what tracking adds), ``lost`` the part of the mean error from frames whose error exceeds
    ``LOST_M``. ``torso``: the trunk's yaw (hip line), forward and sideways lean (pelvis -> neck) and
    the pelvis height, fit minus truth, as ``*_mean`` (signed) and ``*_abs`` (mean magnitude)."""
    names = list(names)
    posed = np.isfinite(pred).all(axis=(1, 2))
    if not posed.any():
        return {"joints": {}, "torso": {}, "frames": 0}
    p, t = np.asarray(pred, float)[posed], np.asarray(truth, float)[posed]
    li, ri, pi, ni = (names.index(j) for j in ("left_hip", "right_hip", "pelvis", "neck"))
    B = heading_frames(t[:, li], t[:, ri])  # (n, 3, 3)
    local = np.einsum("nij,nkj->nki", B, p - t)  # (n, J, 3)
    mean = local.mean(axis=0)
    err = np.linalg.norm(local, axis=-1)
    rest = np.linalg.norm(local - mean, axis=-1).mean(axis=0)
    lost = np.where(err > LOST_M, err, 0.0).mean(axis=0)
    joints = {j: {"error": round(1e3 * float(err[:, k].mean()), 1), "offset_side": round(1e3 * float(mean[k, 0]), 1),
                  "offset_fwd": round(1e3 * float(mean[k, 1]), 1), "offset_up": round(1e3 * float(mean[k, 2]), 1),
                  "offset": round(1e3 * float(np.linalg.norm(mean[k])), 1), "rest": round(1e3 * float(rest[k]), 1),
                  "lost": round(1e3 * float(lost[k]), 1)} for k, j in enumerate(names)}

    def yaw(left, right):
        d = left - right
        return np.arctan2(d[:, 1], d[:, 0])

    def lean(x):  # pelvis -> neck in the truth's heading frame: (forward, sideways) lean, rad
        a = np.einsum("nij,nj->ni", B, x[:, ni] - x[:, pi])
        return np.arctan2(a[:, 1], a[:, 2]), np.arctan2(a[:, 0], a[:, 2])

    d_yaw = np.angle(np.exp(1j * (yaw(p[:, li], p[:, ri]) - yaw(t[:, li], t[:, ri]))))
    (fp, sp), (ft, st) = lean(p), lean(t)
    torso = {}
    for key, v, unit in (("yaw_deg", d_yaw, np.degrees(1.0)), ("lean_fwd_deg", fp - ft, np.degrees(1.0)),
                         ("lean_side_deg", sp - st, np.degrees(1.0)), ("pelvis_up_mm", local[:, pi, 2], 1e3)):
        torso[f"{key}_mean"] = round(float(unit * v.mean()), 2)
        torso[f"{key}_abs"] = round(float(unit * np.abs(v).mean()), 2)
    return {"joints": joints, "torso": torso, "frames": int(posed.sum())}


def offsets(reference: list[dict], poses: list[dict]) -> dict:
    """Joint -> {n, side, fwd, up, fwd_median} in mm over the frames both hold."""
    by_frame = {r["frame"]: r.get("joints") or {} for r in reference if "frame" in r}
    acc: dict[str, list] = {}
    for p in poses:
        ref, ours = by_frame.get(p.get("frame"), {}), p.get("joints") or {}
        if ref.get("left_hip") is None or ref.get("right_hip") is None:
            continue
        B = heading_frame(ref["left_hip"], ref["right_hip"])
        for name, r in ref.items():
            if r is not None and ours.get(name) is not None:
                acc.setdefault(name, []).append(B @ (np.asarray(ours[name], float) - np.asarray(r, float)))
    out = {}
    for name, v in acc.items():
        v = 1e3 * np.asarray(v)
        m = v.mean(axis=0)
        out[name] = {"n": len(v), "side": round(float(m[0]), 1), "fwd": round(float(m[1]), 1),
                     "up": round(float(m[2]), 1), "fwd_median": round(float(np.median(v[:, 1])), 1)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reference", type=Path)
    ap.add_argument("poses", type=Path)
    args = ap.parse_args(argv)
    result = {"offsets_mm": offsets(read_jsonl(args.reference, "reference"), read_jsonl(args.poses, "poses")),
              "machine_ref_ms": round(machine_ref_ms(), 2)}
    print(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
