"""Pose-record files: read/write JSONL, and BVH export of the body model's motion.

BVH layout written by :func:`write_bvh` (Blender: File > Import > Motion Capture (.bvh), set *Up* to Z,
scale 1 = metres):

- one BVH joint per model part, in the model's (topological) order, named like the part; the root has
  ``OFFSET 0 0 0`` and ``CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every
  other part ``OFFSET`` = its joint centre in the parent frame at the reference pose and
  ``CHANNELS 3 Zrotation Xrotation Yrotation``; leaves get an ``End Site`` at the cone's far end.
- per frame: root position = part2world translation of the root; per part the local rotation
  ``parent2world^T · part2world`` as intrinsic Z-X-Y Euler angles in degrees (BVH: ``R = Rz · Rx · Ry``).
- world frame and units are the tracker's: metres, Z up.
- a frame whose record is not ``ok`` (or has no ``params``) repeats the previous good pose (counted in
  the result); frames before the first good one take the first good one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from service.wire.messages import MessageError
from service.wire.records import PoseRecord

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")


class ExportError(ValueError):
    """A pose file cannot be read or exported; the message names the file (and line)."""


@dataclass(frozen=True)
class BvhExport:
    """What :func:`write_bvh` wrote: frames, repeated (not-ok) frames, fps, joints (BVH joints with channels)."""

    path: Path
    frames: int
    repeated: int
    fps: float
    joints: int


def read_pose_records(path) -> list[PoseRecord]:
    """Every pose record of a JSONL file (blank lines skipped); ExportError names ``file:line``."""
    path = Path(path)
    try:
        lines = path.read_bytes().splitlines()
    except OSError as exc:
        raise ExportError(f"{path}: cannot read ({exc.strerror})") from None
    out = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append(PoseRecord.from_bytes(line))
        except MessageError as exc:
            raise ExportError(f"{path}:{i}: {exc}") from None
    return out


def write_pose_records(path, records: Iterable[PoseRecord]) -> int:
    """Write records as JSONL; returns the count."""
    n = 0
    with open(path, "wb") as f:
        for rec in records:
            f.write(rec.to_bytes() + b"\n")
            n += 1
    return n


def fps_from_records(records: Sequence[PoseRecord], default: float = 25.0) -> float:
    """Frame rate from the median timestamp step per frame-id step (``default`` if undetermined)."""
    frames = np.array([r.frame for r in records], float)
    ts = np.array([r.timestamp_ns for r in records], float)
    dframe, dts = np.diff(frames), np.diff(ts)
    ok = (dframe > 0) & (dts > 0)
    if not ok.any():
        return default
    return float(1e9 / np.median(dts[ok] / dframe[ok]))


def _params_matrix(model, records: Sequence[PoseRecord], where: str) -> tuple[np.ndarray, int]:
    """(n_frames, n_params) with not-ok frames filled from the previous good one."""
    good = [i for i, r in enumerate(records) if r.ok and len(r.get("params") or ()) == model.n_params]
    if not good:
        raise ExportError(f"{where}: no ok pose with {model.n_params} params for model {model.name!r}")
    P = np.empty((len(records), model.n_params))
    last = np.asarray(records[good[0]].get("params"), float)
    good_set = set(good)
    for i, r in enumerate(records):
        if i in good_set:
            last = np.asarray(r.get("params"), float)
        P[i] = last
    return P, len(records) - len(good)


def _local_rotations(model, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root translation (n, 3) and parent-relative rotations (n, n_parts, 3, 3) per frame."""
    from tracker.body.kinematics import forward

    n = params.shape[0]
    R = np.empty((n, model.n_parts, 3, 3))
    t0 = np.empty((n, 3))
    for f in range(n):  # one forward-kinematics call per frame (vectorised over parts inside)
        pose = forward(model, params[f])
        R[f] = pose.rotation
        t0[f] = pose.translation[0]
    local = R.copy()
    child = np.flatnonzero(model.parent >= 0)
    local[:, child] = np.swapaxes(R[:, model.parent[child]], -1, -2) @ R[:, child]
    return t0, local


def write_bvh(path, model, records: Sequence[PoseRecord], *, fps: float | None = None) -> BvhExport:
    """Write the motion of ``records`` (fitted with ``model``) as BVH; see the module docstring."""
    from scipy.spatial.transform import Rotation

    path = Path(path)
    if not records:
        raise ExportError(f"{path}: no pose records to export")
    fps = fps or fps_from_records(records)
    params, repeated = _params_matrix(model, records, str(path))
    t0, local = _local_rotations(model, params)
    n, n_parts = local.shape[:2]
    euler = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(n, n_parts, 3)
    children = {p: [c for c in range(n_parts) if model.parent[c] == p] for p in range(n_parts)}
    order: list[int] = []  # depth-first: the order of the hierarchy and of the motion columns

    def visit(p: int) -> None:
        order.append(p)
        for c in children[p]:
            visit(c)

    visit(0)
    motion = np.concatenate([t0, euler[:, order].reshape(n, -1)], axis=1)  # root pos, then ZXY per joint
    lines = ["HIERARCHY"]

    def emit(p: int, depth: int) -> None:
        ind = "  " * depth
        off = np.zeros(3) if model.parent[p] < 0 else model.offset[p]
        head = "ROOT" if model.parent[p] < 0 else "JOINT"
        chans = ROOT_CHANNELS if model.parent[p] < 0 else JOINT_CHANNELS
        lines.extend([f"{ind}{head} {model.part_names[p]}", f"{ind}{{",
                      f"{ind}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}",
                      f"{ind}  CHANNELS {len(chans)} {' '.join(chans)}"])
        for c in children[p]:
            emit(c, depth + 1)
        if not children[p]:
            z2 = float(model.cones[p, 4])
            lines.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET 0.000000 0.000000 {z2:.6f}",
                          f"{ind}  }}"])
        lines.append(f"{ind}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {n}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in motion]
    try:
        path.write_text("\n".join(lines) + "\n")
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return BvhExport(path, n, repeated, fps, n_parts)
