"""Calibration files: read and write the cameras of a studio.

The contract (DESIGN.md) is the anipose / Pose2Sim TOML layout, metres,
world Z up, floor at z = 0::

    [cam_00]
    name = "cam0"
    size = [800, 600]                       # width, height
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]      # OpenCV order; 4 terms accepted
    rotation = [rx, ry, rz]                 # Rodrigues, world -> camera
    translation = [tx, ty, tz]              # world -> camera, metres
    [metadata]
    units = "m"

``save_calibration`` writes exactly this; ``load_calibration`` reads it and
the other flavours of the same layout, converting translations to metres:

* **contourcap** -- ``[metadata] units = "m"`` (or ``"mm"``): as stated.
* **Pose2Sim** -- camera tables carry ``fisheye = false``; Pose2Sim writes
  metres.  ``fisheye = true`` is refused (not an OpenCV pinhole camera).
* **FreeMoCap** -- anipose-based, ``[metadata]`` holds ``charuco_*`` keys;
  translations are in millimetres (the ChArUco square size is given in mm).
* **anipose** -- no unit stated; translations are in the board's unit,
  normally millimetres: when any camera has ``|t| > 100``, every translation
  of the file is read as mm (one decision per file, never per camera).

Other formats (OpenCV XML/YAML, EasyMocap, projection matrices) live in
``capture.calib_formats``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from capture.atomic import write_text_atomic
from capture.camera import Camera, rodrigues_to_matrix
from capture.errors import CaptureError
from capture.tomlio import dumps, load_file

__all__ = ["CalibrationError", "load_calibration", "save_calibration", "cameras_to_toml_dict", "toml_flavour"]


class CalibrationError(CaptureError, ValueError):
    """A calibration file is malformed; the message names file, section and key."""


def cameras_to_toml_dict(cameras: Sequence[Camera]) -> dict:
    """The calibration TOML tables of ``cameras`` (``cam_00`` ... and ``[metadata] units = "m"``)."""
    out: dict = {}
    for i, cam in enumerate(cameras):
        out[f"cam_{i:02d}"] = {
            "name": cam.name,
            "size": [int(cam.width), int(cam.height)],
            "matrix": cam.matrix.tolist(),
            "distortions": cam.distortion.tolist(),
            "rotation": cam.rvec.tolist(),
            "translation": cam.translation.tolist(),
        }
    out["metadata"] = {"units": "m"}
    return out


def save_calibration(path, cameras: Sequence[Camera]) -> Path:
    """Write cameras as an anipose-layout calibration TOML in metres.

    Parameters
    ----------
    path : path
        File written (replaced).
    cameras : sequence of Camera
        Unique names, else ``CalibrationError``.
    """
    path = Path(path)
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise CalibrationError(f"{path}: camera names must be unique, got {names}")
    write_text_atomic(path, dumps(cameras_to_toml_dict(cameras)))
    return path


def _get(table: dict, key: str, where: str):
    if key not in table:
        raise CalibrationError(f"{where}: missing key {key!r}")
    return table[key]


def _array(table: dict, key: str, where: str, shape: tuple | None) -> np.ndarray:
    """``table[key]`` as a finite float array of ``shape`` (``None``: any shape, checked by the caller)."""
    value = _get(table, key, where)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: key {key!r} is not numeric: {exc}") from None
    if shape is not None and arr.shape != shape and not (key == "distortions" and arr.shape == (4,)):
        raise CalibrationError(f"{where}: key {key!r} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{where}: key {key!r} has non-finite values")
    return arr


_MM = ("mm", "millimeter", "millimeters", "millimetre", "millimetres")
_M = ("m", "meter", "meters", "metre", "metres")


def toml_flavour(data: dict) -> str:
    """Which tool wrote a parsed calibration TOML: "contourcap", "pose2sim", "freemocap" or "anipose"."""
    meta = data.get("metadata", {}) if isinstance(data.get("metadata"), dict) else {}
    if "units" in meta:
        return "contourcap"
    if any("charuco" in str(k).lower() for k in meta) or "freemocap" in str(meta).lower():
        return "freemocap"
    if any(isinstance(v, dict) and "fisheye" in v for v in data.values()):
        return "pose2sim"
    return "anipose"


def load_calibration(path) -> list[Camera]:
    """Read an anipose / Pose2Sim / FreeMoCap / contourcap calibration TOML (see module doc) into cameras in metres."""
    path = Path(path)
    data = load_file(path, error=CalibrationError, what="calibration file")
    meta = data.get("metadata", {})
    if not isinstance(meta, dict):
        raise CalibrationError(f"{path}: key 'metadata' must be a table [metadata]")
    flavour = toml_flavour(data)
    units = str(meta.get("units", "")).strip().lower()
    if flavour == "pose2sim":
        units = "m"
    elif flavour == "freemocap":
        units = "mm"
    elif units and units not in _M and units not in _MM:
        raise CalibrationError(f"{path} [metadata]: key 'units' must be \"m\" or \"mm\", got {units!r}")
    sections = [k for k, v in data.items() if isinstance(v, dict) and k != "metadata"]
    if not sections:
        raise CalibrationError(f"{path}: no camera sections found")
    if units not in _M and units not in _MM:  # unit not stated: one decision for the whole file
        norms = [np.linalg.norm(_array(data[s], "translation", f"{path} [{s}]", (3,))) for s in sections]
        units = "mm" if max(norms) > 100.0 else "m"  # a camera over 100 m away: millimetres
    cams = []
    for sec in sections:
        table = data[sec]
        where = f"{path} [{sec}]"
        if table.get("fisheye", False) is True:
            raise CalibrationError(f"{where}: key 'fisheye' is true; only pinhole cameras with OpenCV distortion are supported")
        name = str(table.get("name", sec))
        size = _array(table, "size", where, (2,))
        K = _array(table, "matrix", where, (3, 3))
        dist = _array(table, "distortions", where, (5,))
        rot = _array(table, "rotation", where, None)
        if rot.shape == (3,):
            R = rodrigues_to_matrix(rot)
        elif rot.shape == (3, 3):
            R = rot
        else:
            raise CalibrationError(f"{where}: key 'rotation' must be a Rodrigues vector (3,) or a matrix (3, 3), got {rot.shape}")
        t = _array(table, "translation", where, (3,))
        if units in _MM:
            t = t / 1000.0
        try:
            cams.append(Camera(name, K, dist, R, t, (int(size[0]), int(size[1]))))
        except ValueError as exc:
            raise CalibrationError(f"{where}: {exc}") from None
    names = [c.name for c in cams]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CalibrationError(f"{path}: camera names must be unique, repeated: {repeated}")
    return cams
