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

``save_calibration`` writes exactly this; ``load_calibration`` reads it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from capture.camera import Camera, rodrigues_to_matrix
from capture.tomlio import dumps, load_file

__all__ = ["CalibrationError", "load_calibration", "save_calibration", "cameras_to_toml_dict"]


class CalibrationError(ValueError):
    """A calibration file is malformed; the message names file, section and key."""


def cameras_to_toml_dict(cameras: Sequence[Camera]) -> dict:
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
    """Write cameras as an anipose-layout calibration TOML in metres."""
    path = Path(path)
    names = [c.name for c in cameras]
    if len(set(names)) != len(names):
        raise CalibrationError(f"{path}: camera names must be unique, got {names}")
    path.write_text(dumps(cameras_to_toml_dict(cameras)))
    return path


def _get(table: dict, key: str, where: str):
    if key not in table:
        raise CalibrationError(f"{where}: missing key {key!r}")
    return table[key]


def _array(table: dict, key: str, where: str, shape: tuple) -> np.ndarray:
    value = _get(table, key, where)
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"{where}: key {key!r} is not numeric: {exc}") from None
    if arr.shape != shape and not (key == "distortions" and arr.shape == (4,)):
        raise CalibrationError(f"{where}: key {key!r} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{where}: key {key!r} has non-finite values")
    return arr


def load_calibration(path) -> list[Camera]:
    """Read an anipose/Pose2Sim calibration TOML into cameras (metres).

    ``[metadata] units = "mm"`` (or translations whose norm suggests
    millimetres when no unit is stated: any |t| > 100) is converted to metres.
    """
    path = Path(path)
    try:
        data = load_file(path)
    except FileNotFoundError:
        raise CalibrationError(f"{path}: calibration file not found") from None
    except ValueError as exc:
        raise CalibrationError(str(exc)) from None
    units = str(data.get("metadata", {}).get("units", "")).lower()
    sections = [k for k, v in data.items() if isinstance(v, dict) and k != "metadata"]
    if not sections:
        raise CalibrationError(f"{path}: no camera sections found")
    cams = []
    for sec in sections:
        table = data[sec]
        where = f"{path} [{sec}]"
        name = str(table.get("name", sec))
        size = _array(table, "size", where, (2,))
        K = _array(table, "matrix", where, (3, 3))
        dist = _array(table, "distortions", where, (5,))
        rot = np.asarray(_get(table, "rotation", where), dtype=float)
        if rot.shape == (3,):
            R = rodrigues_to_matrix(rot)
        elif rot.shape == (3, 3):
            R = rot
        else:
            raise CalibrationError(f"{where}: key 'rotation' must be a Rodrigues vector (3,) or a matrix (3, 3), got {rot.shape}")
        t = _array(table, "translation", where, (3,))
        if units in ("mm", "millimeter", "millimeters", "millimetre", "millimetres"):
            t = t / 1000.0
        elif units not in ("m", "meter", "meters", "metre", "metres") and np.linalg.norm(t) > 100.0:
            t = t / 1000.0  # unit not stated; a camera over 100 m away is millimetres
        try:
            cams.append(Camera(name, K, dist, R, t, (int(size[0]), int(size[1]))))
        except ValueError as exc:
            raise CalibrationError(f"{where}: {exc}") from None
    return cams
