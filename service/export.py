"""Pose-record files: read/write JSONL, and BVH export of the body model's motion.

BVH layout written by :func:`write_bvh` (Blender: File > Import > Motion Capture (.bvh) with its default
settings; scale 1 = metres):

- one BVH joint per model part, in the model's (topological) order, named like the part; the root has
  ``OFFSET 0 0 0`` and ``CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation``, every
  other part ``OFFSET`` = its joint centre minus its parent's at the model's T-pose (world axes) and
  ``CHANNELS 3 Zrotation Xrotation Yrotation``; leaves get an ``End Site`` at the cone's far end.
  With every channel 0 the skeleton stands in that T-pose.
- per frame: root position = the root part's origin; per part the T-pose-relative local rotation of
  :mod:`tracker.body.joint_frames` (shared with the VMC stream) as intrinsic Z-X-Y Euler angles in degrees
  (BVH: ``R = Rz · Rx · Ry``).
- axes: ``up="y"`` (default, what BVH readers assume) writes tracker world ``(x, y, z)`` as
  ``(x, z, -y)`` (−90° about X); ``up="z"`` writes the tracker's Z-up world as is.  Metres.
- time: one BVH frame per frame id from the first record's to the last's at the session's frame rate
  (``Frame Time`` = 1 / fps), so a take whose frame ids jump plays at its real speed.  A frame id without
  an ok record (not ok, no ``params``, or never delivered) *holds* the previous good pose (counted in
  the result); frames before the first good one take the first good one.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from service.atomic import write_text_atomic
from service.wire.messages import MessageError
from service.wire.records import PoseRecord
from service.outputs.posefile import ExportError, fps_from_records, read_pose_records, write_pose_records  # noqa: F401 (re-exported)

ROOT_CHANNELS = ("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")
JOINT_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")










@dataclass(frozen=True)
class BvhExport:
    """What :func:`write_bvh` wrote: frames (frame ids spanned), repeated (frames holding the previous
    good pose: not ok or missing), fps, joints (BVH joints with channels), the first frame id, the up axis."""

    path: Path
    frames: int
    repeated: int
    fps: float
    joints: int
    first_frame: int = 0
    up: str = "y"


def _params_matrix(model, records: Sequence[PoseRecord], rows: np.ndarray, where: str) -> tuple[np.ndarray, int]:
    """(n_rows, n_params): row k takes record ``rows[k]`` (−1: none) if it is ok with params, else holds
    the previous good row (the first good one before it); returns the matrix and the held-row count."""
    good_rec = np.array([r.ok and len(r.get("params") or ()) == model.n_params for r in records], dtype=bool)
    if not good_rec.any():
        raise ExportError(f"{where}: no ok pose with {model.n_params} params for model {model.name!r}")
    good_row = (rows >= 0) & good_rec[np.maximum(rows, 0)]
    src = np.where(good_row, np.arange(rows.size), -1)
    src = np.maximum.accumulate(src)
    src[src < 0] = np.flatnonzero(good_row)[0]
    recs = rows[src]
    table = {int(i): np.asarray(records[int(i)].get("params"), float) for i in np.unique(recs)}
    P = np.stack([table[int(i)] for i in recs])
    return P, int(rows.size - good_row.sum())


def write_bvh(path, model, records: Sequence[PoseRecord], *, fps: float | None = None,
              up: str = "y") -> BvhExport:
    """Write the motion of ``records`` (fitted with ``model``) as BVH; see the module docstring.

    Parameters
    ----------
    fps : float, optional
        Frame rate (default: from the records' timestamps per frame-id step).
    up : {"y", "z"}
        Up axis of the file.
    """
    from scipy.spatial.transform import Rotation

    from service.outputs.timeline import make_timeline
    from tracker.body.joint_frames import axes_for, joint_frames

    path = Path(path)
    if not records:
        raise ExportError(f"{path}: no pose records to export")
    try:
        axes = axes_for(up)
    except ValueError as exc:
        raise ExportError(f"{path}: {exc}") from None
    tl = make_timeline(records, fps=fps, where=str(path))
    fps = tl.fps
    params, repeated = _params_matrix(model, records, tl.record, str(path))
    jf = joint_frames(model, params, axes)
    local = jf.local
    n, n_parts = local.shape[:2]
    euler = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True).reshape(n, n_parts, 3)
    children = {p: [c for c in range(n_parts) if model.parent[c] == p] for p in range(n_parts)}
    order: list[int] = []  # depth-first: the order of the hierarchy and of the motion columns

    def visit(p: int) -> None:
        order.append(p)
        for c in children[p]:
            visit(c)

    visit(0)
    motion = np.concatenate([jf.root_position, euler[:, order].reshape(n, -1)], axis=1)  # root pos, then ZXY per joint
    lines = ["HIERARCHY"]

    def emit(p: int, depth: int) -> None:
        ind = "  " * depth
        off = np.zeros(3) if model.parent[p] < 0 else jf.rest_offset[p]
        head = "ROOT" if model.parent[p] < 0 else "JOINT"
        chans = ROOT_CHANNELS if model.parent[p] < 0 else JOINT_CHANNELS
        lines.extend([f"{ind}{head} {model.part_names[p]}", f"{ind}{{",
                      f"{ind}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}",
                      f"{ind}  CHANNELS {len(chans)} {' '.join(chans)}"])
        for c in children[p]:
            emit(c, depth + 1)
        if not children[p]:
            e = jf.end_site[p]
            lines.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET {e[0]:.6f} {e[1]:.6f} {e[2]:.6f}",
                          f"{ind}  }}"])
        lines.append(f"{ind}}}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {n}", f"Frame Time: {1.0 / fps:.8f}"]
    lines += [" ".join(f"{v:.6f}" for v in row) for row in motion]
    try:
        write_text_atomic(path, "\n".join(lines) + "\n")
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return BvhExport(path, n, repeated, fps, n_parts, int(tl.frames[0]), str(up).lower())
