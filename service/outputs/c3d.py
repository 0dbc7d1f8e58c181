"""C3D marker files through the ``c3d`` package (py-c3d; pure Python, numpy only).

- one point per joint, labelled with the pose record's joint name; ``POINT:RATE`` = the session's frame
  rate; ``POINT:UNITS`` = ``mm`` or ``m``; float storage (``POINT:SCALE`` < 0).
- one C3D frame per frame id from the first record's to the last's.  C3D counts frames from 1, so the
  header's first frame (and ``TRIAL:ACTUAL_START_FIELD``) is the first record's frame id **+ 1**: C3D
  frame k is pose frame k − 1.
- a point of a frame without an ok record has residual −1 (invalid: readers show a gap); valid points
  have residual 0 and an empty camera mask.
- axes: ``POINT:X_SCREEN``/``Y_SCREEN`` are ``+X``/``+Z`` for Z-up files and ``+X``/``+Y`` for Y-up ones.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from service.atomic import atomic_open
from service.export import ExportError
from service.outputs.timeline import Timeline

INSTALL_HINT = "C3D export needs the 'c3d' package: pip install c3d"


def write_c3d(path, tl: Timeline, names: Sequence[str], markers: np.ndarray, *, units: str, up: str) -> Path:
    """Write markers (n_rows, n_markers, 3) in ``units`` on timeline ``tl``; ``up`` names the vertical axis."""
    path = Path(path)
    try:
        import c3d
    except ImportError:
        raise ExportError(f"{path}: {INSTALL_HINT}") from None
    if units not in ("mm", "m"):
        raise ExportError(f"{path}: units must be mm or m, got {units!r}")
    n_rows, n_markers = markers.shape[:2]
    writer = c3d.Writer(point_rate=float(tl.fps), analog_rate=0.0, point_scale=-1.0, point_units=units)
    writer.set_point_labels(list(names))
    writer.set_screen_axis("+X", "+Z" if up == "z" else "+Y")
    writer.set_start_frame(int(tl.frames[0]) + 1)
    pts = np.zeros((n_rows, n_markers, 5), dtype=np.float32)
    valid = ~np.isnan(markers).any(axis=-1)
    pts[..., :3] = np.where(valid[..., None], markers, 0.0)
    pts[..., 3] = np.where(valid, 0.0, -1.0)
    no_analog = np.zeros((0, 0), dtype=np.float32)
    writer.add_frames([(pts[k], no_analog) for k in range(n_rows)])
    try:
        with atomic_open(path, "wb") as f, warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="No analog data")
            writer.write(f)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return path
