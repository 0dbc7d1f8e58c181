"""Other calibration file formats: OpenCV FileStorage, EasyMocap, 3×4 projection matrices.

Every reader returns ``list[Camera]`` in contourcap's convention (world2cam,
metres, OpenCV distortion order); every malformed file raises
``CalibrationError`` naming the file, the section/camera and the key.

Formats
-------
* **OpenCV FileStorage, one camera per file** (XML or YAML), e.g. the
  uu_studio ``camN/config.xml``: ``CameraMatrix`` (3×3), ``DistortionCoeffs``
  (4 or 5), ``Rotation`` (Rodrigues 3×1 or matrix 3×3, world2cam),
  ``Translation`` (3×1).  Common aliases (``camera_matrix``, ``K``,
  ``distortion_coefficients``, ``rvec``, ``tvec`` …) are accepted.  Units:
  an optional ``units`` string (``"m"``/``"mm"``); without it, a translation
  longer than 100 is taken as millimetres (the uu_studio files are mm).
  Image size from ``image_width``/``image_height`` (or ``ImageSize``/``size``)
  when present, else the ``size=`` argument, else ``2 * (cx, cy)`` rounded.
* **EasyMocap** ``intri.yml`` + ``extri.yml``: ``names`` (list of strings),
  ``K_<name>``, ``dist_<name>`` in intri; ``Rot_<name>`` (3×3) or ``R_<name>``
  (Rodrigues) and ``T_<name>`` (metres) in extri.  EasyMocap stores no image
  size; we write and read optional ``W_<name>``/``H_<name>``, else size is
  ``2 * (cx, cy)`` rounded (as Pose2Sim's converter does).
* **Projection matrix** ``camXX.xml``/``.txt``: 12 numbers, row-major 3×4
  ``P = K [R | t]`` in pixels (world metres).  Decomposed by RQ into ``K``
  with positive focal lengths (skew kept) and a proper rotation; distortion 0.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np
from scipy.linalg import rq

from capture.atomic import write_text_atomic
from capture.calibration import CalibrationError, load_calibration, save_calibration
from capture.camera import Camera

__all__ = [
    "read_opencv_camera",
    "write_opencv_camera",
    "read_easymocap",
    "write_easymocap",
    "read_projection_matrix",
    "write_projection_matrix",
    "decompose_projection_matrix",
    "read_any_calibration",
    "open_storage",
]

_K_KEYS = ("CameraMatrix", "camera_matrix", "cameraMatrix", "K", "intrinsic", "M")
_D_KEYS = ("DistortionCoeffs", "distortion_coefficients", "distCoeffs", "dist_coeffs", "dist", "D")
_R_KEYS = ("Rotation", "rotation", "rvec", "R")
_T_KEYS = ("Translation", "translation", "tvec", "T")
_MM_UNITS = ("mm", "millimeter", "millimeters", "millimetre", "millimetres")
_M_UNITS = ("m", "meter", "meters", "metre", "metres")


def open_storage(path: Path, *, what: str = "calibration file") -> cv2.FileStorage:
    """Open an OpenCV FileStorage XML/YAML file for reading; ``CalibrationError`` naming it otherwise."""
    if not path.is_file():
        raise CalibrationError(f"{path}: {what} not found")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise CalibrationError(f"{path}: not a readable OpenCV FileStorage file: {str(exc).splitlines()[-1]}") from None
    except SystemError:  # what OpenCV's parser raises on text that is not XML/YAML at all
        raise CalibrationError(f"{path}: not a readable OpenCV FileStorage file (XML or YAML)") from None
    if not fs.isOpened():
        raise CalibrationError(f"{path}: not a readable OpenCV FileStorage file")
    return fs


def _node_matrix(fs: cv2.FileStorage, key: str, where: str, sizes: Sequence[int]) -> np.ndarray:
    node = fs.getNode(key)
    if node.empty():
        raise CalibrationError(f"{where}: missing key {key!r}")
    try:
        mat = node.mat()
    except cv2.error:  # e.g. a text node
        mat = None
    if mat is None:
        if node.isSeq():
            mat = np.array([_number(node.at(i), where, key) for i in range(node.size())])
        else:
            raise CalibrationError(f"{where}: key {key!r} is not a matrix")
    arr = np.asarray(mat, dtype=float).ravel()
    if arr.size not in sizes:
        raise CalibrationError(f"{where}: key {key!r} must hold {' or '.join(map(str, sizes))} numbers, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{where}: key {key!r} has non-finite values")
    return arr


def _number(node, where: str, key: str) -> float:
    """A FileStorage node's number; ``real()`` of a text node is junk (1.8e308), so it is refused."""
    if not (node.isInt() or node.isReal()):
        raise CalibrationError(f"{where}: key {key!r} must hold numbers")
    return node.real()


def _first_key(fs: cv2.FileStorage, keys: Sequence[str], where: str, what: str) -> str:
    for k in keys:
        if not fs.getNode(k).empty():
            return k
    raise CalibrationError(f"{where}: missing key {keys[0]!r} ({what}; also accepted: {', '.join(keys[1:])})")


def _units_scale(units: str, t: np.ndarray) -> float:
    units = units.strip().lower()
    if units in _MM_UNITS:
        return 1e-3
    if units in _M_UNITS:
        return 1.0
    return 1e-3 if np.linalg.norm(t) > 100.0 else 1.0


def _size_from_center(K: np.ndarray) -> tuple[int, int]:
    return int(round(2 * K[0, 2])), int(round(2 * K[1, 2]))


def _make_camera(name, K, dist, rot, t, size, where) -> Camera:
    R = rot.reshape(3, 3) if rot.size == 9 else rot.reshape(3)
    try:
        return Camera(name, K.reshape(3, 3), dist, R, t.reshape(3), size)
    except ValueError as exc:
        raise CalibrationError(f"{where}: {exc}") from None


def read_opencv_camera(path, *, name: str | None = None, size: tuple[int, int] | None = None, units: str | None = None) -> Camera:
    """Read one camera from an OpenCV FileStorage XML/YAML file (see module doc).

    ``name`` defaults to the file's parent folder name for ``config.xml``-style
    files (``cam1/config.xml`` -> ``"cam1"``), else the file stem.
    """
    path = Path(path)
    fs = open_storage(path)
    where = f"{path} [root]"
    K = _node_matrix(fs, _first_key(fs, _K_KEYS, where, "camera matrix"), where, (9,))
    dist = _node_matrix(fs, _first_key(fs, _D_KEYS, where, "distortion"), where, (4, 5, 8, 12, 14))
    if np.any(dist[5:] != 0):
        raise CalibrationError(f"{where}: only 4 or 5 distortion terms (k1, k2, p1, p2, k3) are supported")
    dist = dist[:5]
    rot = _node_matrix(fs, _first_key(fs, _R_KEYS, where, "world2cam rotation"), where, (3, 9))
    t = _node_matrix(fs, _first_key(fs, _T_KEYS, where, "world2cam translation"), where, (3,))
    unit_node = fs.getNode("units")
    file_units = unit_node.string() if not unit_node.empty() else ""
    t = t * _units_scale(units if units is not None else file_units, t)
    if size is None:
        for wk, hk in (("image_width", "image_height"), ("ImageWidth", "ImageHeight"), ("width", "height")):
            if not fs.getNode(wk).empty() and not fs.getNode(hk).empty():
                size = (int(_number(fs.getNode(wk), where, wk)), int(_number(fs.getNode(hk), where, hk)))
                break
    if size is None:
        for sk in ("ImageSize", "image_size", "size"):
            if not fs.getNode(sk).empty():
                wh = _node_matrix(fs, sk, where, (2,))
                size = (int(wh[0]), int(wh[1]))
                break
    if size is None:
        size = _size_from_center(K.reshape(3, 3))
    if name is None:
        name = path.parent.name if path.stem.lower() in ("config", "calibration", "camera") else path.stem
    return _make_camera(name, K, dist, rot, t, size, where)


def write_opencv_camera(path, camera: Camera) -> Path:
    """Write one camera as OpenCV FileStorage (XML or YAML by suffix), metres, ``units = "m"``."""
    path = Path(path)
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("CameraMatrix", camera.matrix)
    fs.write("DistortionCoeffs", camera.distortion.reshape(1, 5))
    fs.write("Rotation", camera.rvec.reshape(3, 1))
    fs.write("Translation", camera.translation.reshape(3, 1))
    fs.write("image_width", int(camera.width))
    fs.write("image_height", int(camera.height))
    fs.write("units", "m")
    fs.release()
    return path


def read_easymocap(intri_path, extri_path) -> list[Camera]:
    """Read EasyMocap ``intri.yml`` + ``extri.yml`` (translations in metres)."""
    intri_path, extri_path = Path(intri_path), Path(extri_path)
    fi, fe = open_storage(intri_path), open_storage(extri_path)
    node = fi.getNode("names")
    if node.empty() or not node.isSeq():
        raise CalibrationError(f"{intri_path} [root]: missing key 'names' (list of camera names)")
    names = [node.at(i).string() or str(int(node.at(i).real())) for i in range(node.size())]
    cams = []
    for name in names:
        wi, we = f"{intri_path} [camera {name}]", f"{extri_path} [camera {name}]"
        K = _node_matrix(fi, f"K_{name}", wi, (9,))
        dist = _node_matrix(fi, f"dist_{name}", wi, (4, 5))
        if not fe.getNode(f"Rot_{name}").empty():
            rot = _node_matrix(fe, f"Rot_{name}", we, (9,))
        else:
            rot = _node_matrix(fe, f"R_{name}", we, (3,))
        t = _node_matrix(fe, f"T_{name}", we, (3,))
        if not fi.getNode(f"W_{name}").empty() and not fi.getNode(f"H_{name}").empty():
            size = (int(_number(fi.getNode(f"W_{name}"), wi, f"W_{name}")),
                    int(_number(fi.getNode(f"H_{name}"), wi, f"H_{name}")))
        else:
            size = _size_from_center(K.reshape(3, 3))
        cams.append(_make_camera(name, K, dist, rot, t, size, we))
    return cams


def write_easymocap(folder, cameras: Sequence[Camera]) -> tuple[Path, Path]:
    """Write ``intri.yml`` and ``extri.yml`` into ``folder`` (metres); returns both paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    intri, extri = folder / "intri.yml", folder / "extri.yml"
    fi = cv2.FileStorage(str(intri), cv2.FILE_STORAGE_WRITE)
    fe = cv2.FileStorage(str(extri), cv2.FILE_STORAGE_WRITE)
    names = [c.name for c in cameras]
    fi.write("names", names)
    fe.write("names", names)
    for c in cameras:
        fi.write(f"K_{c.name}", c.matrix)
        fi.write(f"dist_{c.name}", c.distortion.reshape(1, 5))
        fi.write(f"W_{c.name}", int(c.width))
        fi.write(f"H_{c.name}", int(c.height))
        fe.write(f"R_{c.name}", c.rvec.reshape(3, 1))
        fe.write(f"Rot_{c.name}", c.rotation)
        fe.write(f"T_{c.name}", c.translation.reshape(3, 1))
    fi.release()
    fe.release()
    return intri, extri


def decompose_projection_matrix(P: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split ``P`` (3, 4) into ``K`` (3, 3; fx, fy > 0, K[2,2] = 1), world2cam ``R`` (proper) and ``t`` (3,).

    ``P`` is defined up to a non-zero scale (sign included); the sign is
    chosen so that ``det(R) = +1``, which puts the scene in front of the camera
    for a physical camera.
    """
    P = np.asarray(P, dtype=float).reshape(3, 4)
    M = P[:, :3]
    if abs(np.linalg.det(M)) < 1e-12 * max(1.0, np.abs(M).max() ** 3):
        raise ValueError("projection matrix has a singular left 3x3 block")
    if np.linalg.det(M) < 0:
        P = -P
        M = P[:, :3]
    K, R = rq(M)
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R  # D @ D = I, so K R is unchanged
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def read_projection_matrix(path, *, name: str | None = None, size: tuple[int, int] | None = None) -> Camera:
    """Read a 12-number row-major projection matrix file (XML wrapper or plain text)."""
    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found")
    text = re.sub(r"<[^>]*>", " ", path.read_text(errors="replace"))
    try:
        nums = np.array([float(v) for v in text.split()])
    except ValueError as exc:
        raise CalibrationError(f"{path} [projection matrix]: not a list of 12 numbers: {exc}") from None
    if nums.size != 12 or not np.all(np.isfinite(nums)):
        raise CalibrationError(f"{path} [projection matrix]: expected 12 finite numbers (row-major 3x4), got {nums.size}")
    try:
        K, R, t = decompose_projection_matrix(nums.reshape(3, 4))
    except ValueError as exc:
        raise CalibrationError(f"{path} [projection matrix]: {exc}") from None
    size = size if size is not None else _size_from_center(K)
    return _make_camera(name or path.stem, K, np.zeros(5), R, t, size, f"{path} [projection matrix]")


def write_projection_matrix(path, camera: Camera) -> Path:
    """Write ``camera.projection_matrix`` as 12 numbers in the dancer_8view XML wrapper (distortion is lost)."""
    if np.any(camera.distortion != 0):
        raise ValueError(f"camera {camera.name!r}: a projection matrix cannot hold lens distortion")
    path = Path(path)
    row = " ".join(repr(float(v)) for v in camera.projection_matrix.ravel())
    write_text_atomic(path, f'<?xml version="1.0" encoding="UTF-8" ?>\n<camera>\n{row}\n</camera>\n')
    return path


def _is_projection_file(path: Path) -> bool:
    text = path.read_text(errors="replace")
    if "opencv_storage" in text or text.lstrip().startswith("%YAML"):
        return False
    return len(re.sub(r"<[^>]*>", " ", text).split()) == 12


def _unique_names(folder: Path, cameras: list[Camera]) -> list[Camera]:
    names = [c.name for c in cameras]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise CalibrationError(f"{folder}: several files describe camera(s) {repeated}")
    return cameras


def read_any_calibration(path, *, size: tuple[int, int] | None = None) -> list[Camera]:
    """Read cameras from any supported file or folder, sniffing the format.

    * ``*.toml`` -> anipose / Pose2Sim / FreeMoCap (``load_calibration``);
    * a folder with ``intri.yml`` + ``extri.yml`` -> EasyMocap;
    * a folder of ``*.xml``/``*.txt`` projection matrices -> one camera each (sorted by name);
    * a folder of ``camN/config.xml`` -> one OpenCV camera each (uu_studio layout);
    * a single ``.xml``/``.yml``/``.yaml``/``.txt`` -> OpenCV camera or projection matrix.

    ``size`` (width, height) is used where the format stores no image size.
    """
    path = Path(path)
    if path.is_dir():
        if (path / "intri.yml").is_file() and (path / "extri.yml").is_file():
            return read_easymocap(path / "intri.yml", path / "extri.yml")
        if (path / "calibration.toml").is_file():
            return load_calibration(path / "calibration.toml")
        configs = sorted(path.glob("*/config.xml"))
        if configs:
            return _unique_names(path, [read_opencv_camera(p, size=size) for p in configs])
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in (".xml", ".txt", ".yml", ".yaml"))
        if not files:
            raise CalibrationError(f"{path}: no calibration files found in this folder")
        return _unique_names(path, [read_any_calibration(p, size=size)[0] for p in files])
    if not path.exists():
        raise CalibrationError(f"{path}: calibration file not found")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return load_calibration(path)
    if suffix in (".xml", ".txt") and _is_projection_file(path):
        return [read_projection_matrix(path, size=size)]
    if suffix in (".xml", ".yml", ".yaml"):
        return [read_opencv_camera(path, size=size)]
    raise CalibrationError(f"{path}: unknown calibration format (expected .toml, .xml, .yml, .yaml, .txt or a folder)")


def write_calibration_as(path, cameras: Sequence[Camera], *, fmt: str) -> list[Path]:
    """Write cameras in ``fmt`` in {"toml", "opencv-xml", "opencv-yaml", "easymocap", "projection"}.

    Single-camera formats write one file per camera into the folder ``path``.
    """
    path = Path(path)
    if fmt == "toml":
        return [save_calibration(path, cameras)]
    if fmt == "easymocap":
        return list(write_easymocap(path, cameras))
    path.mkdir(parents=True, exist_ok=True)
    if fmt in ("opencv-xml", "opencv-yaml"):
        ext = ".xml" if fmt == "opencv-xml" else ".yml"
        return [write_opencv_camera(path / f"{c.name}{ext}", c) for c in cameras]
    if fmt == "projection":
        return [write_projection_matrix(path / f"{c.name}.xml", c) for c in cameras]
    raise ValueError(f"unknown calibration format {fmt!r}")
