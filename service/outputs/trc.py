"""TRC marker files as OpenSim's ``TRCFileAdapter`` (and Pose2Sim) read them.

Layout (tab separated; every data and label line ends with a tab, as OpenSim writes them)::

    PathFileType  4  (X/Y/Z)  <file name>
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    <fps>  <fps>  <rows>  <markers>  mm|m  <fps>  <first frame id>  <rows>
    Frame#  Time  <marker 1>  ""  ""  <marker 2> ...
    ""  ""  X1  Y1  Z1  X2 ...
    <blank line>
    <frame id>  <seconds since the first frame>  x  y  z ...

One row per frame id from the first record's to the last's; a marker of a frame without an ok record
(not ok, or never delivered) is three empty cells, which OpenSim reads as NaN (a gap).
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from service.atomic import write_text_atomic
from service.export import ExportError
from service.outputs.timeline import Timeline


def _cells(values: np.ndarray, decimals: int) -> np.ndarray:
    """Formatted numbers, "" for NaN; values any shape -> same shape of str."""
    flat = values.ravel()
    out = np.array([("" if np.isnan(v) else f"{v:.{decimals}f}") for v in flat], dtype=object)
    return out.reshape(values.shape)


def write_trc(path, tl: Timeline, names: Sequence[str], markers: np.ndarray, *, units: str) -> Path:
    """Write markers (n_rows, n_markers, 3) in ``units`` ("mm" or "m") on timeline ``tl``; returns the path."""
    path = Path(path)
    if units not in ("mm", "m"):
        raise ExportError(f"{path}: units must be mm or m, got {units!r}")
    for name in names:
        if not name or any(c in name for c in "\t\r\n"):
            raise ExportError(f"{path}: marker name {name!r} cannot be written to TRC")
    n_rows, n_markers = markers.shape[:2]
    decimals = 5 if units == "mm" else 8
    rate = f"{tl.fps:.6g}"
    lines = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
        f"{rate}\t{rate}\t{n_rows}\t{n_markers}\t{units}\t{rate}\t{int(tl.frames[0])}\t{n_rows}",
        "Frame#\tTime\t" + "".join(f"{n}\t\t\t" for n in names),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, n_markers + 1)),
        "",
    ]
    cells = _cells(markers.reshape(n_rows, -1), decimals)
    times = tl.times_s
    for k in range(n_rows):
        lines.append(f"{int(tl.frames[k])}\t{times[k]:.6f}\t" + "".join(c + "\t" for c in cells[k]))
    try:
        write_text_atomic(path, "\n".join(lines) + "\n")
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return path
