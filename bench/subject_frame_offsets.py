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


def heading_frame(left_hip: np.ndarray, right_hip: np.ndarray) -> np.ndarray:
    """Rows (side, fwd, up) of the pelvis heading frame from the hip joints, shape (3, 3)."""
    side = np.asarray(left_hip, float) - np.asarray(right_hip, float)
    side[2] = 0.0
    side /= max(float(np.linalg.norm(side)), 1e-9)
    up = np.array([0.0, 0.0, 1.0])
    return np.stack([side, np.cross(side, up), up])


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
