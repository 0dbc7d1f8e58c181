"""Pose files: reading and writing ``poses.jsonl`` (one pose record per line), and their frame rate.

Every file output (BVH, TRC, C3D, CSV) and every replayed stream reads its records here.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from service.atomic import atomic_open
from service.errors import ServiceError
from service.text import printable
from service.wire.messages import MessageError
from service.wire.records import PoseRecord

__all__ = ["ExportError", "PoseFile", "read_pose_file", "read_pose_records", "write_pose_records", "fps_from_records"]


log = logging.getLogger(__name__)


class ExportError(ServiceError, ValueError):
    """A pose file cannot be read or exported; the message names the file (and line)."""



@dataclass(frozen=True)
class PoseFile:
    """What :func:`read_pose_file` read: the records, and the lines it skipped as ``(line number, why)``
    (``cut_last_line``: the file ends in a record cut short, as a power cut or a kill leaves it)."""

    path: Path
    records: list[PoseRecord]
    skipped: tuple[tuple[int, str], ...] = ()
    cut_last_line: bool = False

    def report(self) -> str | None:
        """One line saying what was skipped (None when nothing was)."""
        if not self.skipped:
            return None
        first = "; ".join(f"line {i}: {why}" for i, why in self.skipped[:3])
        more = f" (and {len(self.skipped) - 3} more)" if len(self.skipped) > 3 else ""
        cut = " - the last line is cut short (the take was interrupted)" if self.cut_last_line else ""
        return f"{self.path}: skipped {len(self.skipped)} line(s){cut}: {first}{more}"


def read_pose_file(path, *, skip_bad: bool = False) -> PoseFile:
    """The pose records of a JSONL file (blank lines skipped).

    A last line without its newline that does not parse (a record cut short) is skipped and reported;
    any other malformed line is an ExportError naming ``file:line`` unless ``skip_bad`` (then it is
    skipped and reported too).  Bytes that are not UTF-8 JSON are malformed lines like any other.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise ExportError(f"{path}: cannot read ({exc.strerror})") from None
    lines = data.splitlines()
    ends_cut = bool(data) and not data.endswith((b"\n", b"\r"))
    out, skipped, cut = [], [], False
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            out.append(PoseRecord.from_bytes(line))
        except MessageError as exc:
            why = printable(exc, limit=160)
            if i == len(lines) and ends_cut:
                cut = True
                skipped.append((i, f"cut short ({why})"))
            elif skip_bad:
                skipped.append((i, why))
            else:
                raise ExportError(f"{path}:{i}: {why} (--skip-bad skips malformed lines)") from None
    return PoseFile(path, out, tuple(skipped), cut)


def read_pose_records(path, *, skip_bad: bool = False) -> list[PoseRecord]:
    """The records of :func:`read_pose_file` (a cut last line skipped; what was skipped is logged)."""
    pf = read_pose_file(path, skip_bad=skip_bad)
    if pf.skipped:
        log.warning("%s", pf.report())
    return pf.records


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
