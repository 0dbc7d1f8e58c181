"""A plain CSV of joint centres: one row per pose record (frame ids as recorded, no filled rows).

Columns: ``frame, time_s, ok, <joint>_x, <joint>_y, <joint>_z, ...`` in the chosen units and axes;
``time_s`` is seconds since the first record at the session's frame rate; the coordinates of a frame
that is not ok are empty cells.
"""

from __future__ import annotations

import csv as _csv
from pathlib import Path
from typing import Sequence

import numpy as np

from service.atomic import atomic_open
from service.export import ExportError
from service.outputs.timeline import Timeline


def write_csv(path, tl: Timeline, names: Sequence[str], markers: np.ndarray) -> Path:
    """Write the rows of ``tl`` that have a record; markers (n_rows, n_markers, 3) as from ``marker_array``."""
    path = Path(path)
    header = ["frame", "time_s", "ok"] + [f"{n}_{a}" for n in names for a in "xyz"]
    rows = np.flatnonzero(tl.record >= 0)
    try:
        with atomic_open(path, "w", newline="") as f:
            w = _csv.writer(f)
            w.writerow(header)
            times = tl.times_s
            for k in rows:
                vals = markers[k].ravel()
                w.writerow([int(tl.frames[k]), f"{times[k]:.6f}", int(tl.ok[k])]
                           + ["" if np.isnan(v) else f"{v:.6f}" for v in vals])
    except OSError as exc:
        raise ExportError(f"{path}: cannot write ({exc.strerror})") from None
    return path
