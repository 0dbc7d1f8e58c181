"""Pose files: reading and writing ``poses.jsonl`` (one pose record per line), and their frame rate.

Every file output (BVH, TRC, C3D, CSV) and every replayed stream reads its records here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from service.atomic import atomic_open
from service.errors import ServiceError
from service.wire.messages import MessageError
from service.wire.records import PoseRecord

__all__ = ["ExportError", "read_pose_records", "write_pose_records", "fps_from_records"]


class ExportError(ServiceError, ValueError):
    """A pose file cannot be read or exported; the message names the file (and line)."""



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
    with atomic_open(path, "wb") as f:
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
