"""Wire messages: typed, immutable, versioned records with ``to_bytes``/``from_bytes``.

Binary records (camera frames, chamfer/distance images) share one layout, readable from any
language without this package::

    offset  size  field
    0       4     magic  b"CCAP"
    4       1     type   (1 = frame, 2 = chamfer)
    5       1     version (currently 1)
    6       2     reserved, 0
    8       4     meta_len     (little-endian uint32)
    12      4     payload_len  (little-endian uint32)
    16      ...   meta: UTF-8 JSON object (field names below), then payload: raw array bytes (C order)

Pose records, status/stats and lossless-mode credits are plain UTF-8 JSON objects (the pose record
is exactly the DESIGN.md object).

Everything that arrives over the network is untrusted: ``from_bytes`` checks sizes against
``max_bytes`` before parsing, the type and version, that ``prod(shape) * itemsize == payload bytes``,
that numbers are finite and camera names are short safe strings.  Any problem raises
:class:`MessageError` (a ``ValueError``) naming the field; nothing else escapes.  No pickle, no eval.
"""

from __future__ import annotations

import json
import math
import re
import struct
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from service.errors import ServiceError

MAGIC = b"CCAP"
HEADER = struct.Struct("<4sBBHII")
TYPE_FRAME = 1
TYPE_CHAMFER = 2
VERSION = 1
MAX_BYTES = 64 * 1024 * 1024
MAX_META_BYTES = 64 * 1024
MAX_DIM = 16384
ENCODINGS = ("raw", "jpeg", "png")
DTYPES = {"uint8": np.uint8, "uint16": np.uint16, "float32": np.float32}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


class MessageError(ServiceError, ValueError):
    """A message that cannot be decoded or fails validation (the text names the field)."""


# ---------------------------------------------------------------------------------------------
# validation helpers (shared by every record)


def check_name(value: Any, what: str = "camera") -> str:
    """A short safe identifier (letters, digits, ``_ . -``; max 64) or :class:`MessageError`."""
    if not isinstance(value, str) or not _NAME.match(value):
        raise MessageError(f"{what}: not a short safe name: {value!r:.80}")
    return value


def meta_int(meta: Mapping, key: str, *, lo: int = 0, hi: int = 2**63 - 1) -> int:
    """An integer field of untrusted decoded meta, validated.

    Parameters
    ----------
    meta : mapping
        Decoded JSON object (e.g. the meta of :func:`unpack_message`).
    key : str
        Field name; it is named in the error.
    lo, hi : int
        Inclusive bounds.

    Returns
    -------
    int
        ``meta[key]``; :class:`MessageError` if absent, a bool, not an int or out of bounds.
    """
    v = meta.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise MessageError(f"{key}: expected an integer in [{lo}, {hi}], got {v!r:.80}")
    return v


def meta_float(meta: Mapping, key: str) -> float:
    """A finite number field of untrusted decoded meta as ``float``; :class:`MessageError` otherwise.

    Parameters
    ----------
    meta : mapping
        Decoded JSON object.
    key : str
        Field name; it is named in the error.
    """
    v = meta.get(key)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise MessageError(f"{key}: expected a finite number, got {v!r:.80}")
    return float(v)


def _shape(value: Any, key: str, ndims: tuple[int, ...], *, allow_empty: bool = False) -> tuple[int, ...]:
    if not isinstance(value, (list, tuple)) or len(value) not in ndims:
        raise MessageError(f"{key}: expected a list of {ndims} dimensions, got {value!r:.80}")
    out = []
    lo = 0 if allow_empty else 1
    for d in value:
        if isinstance(d, bool) or not isinstance(d, int) or not lo <= d <= MAX_DIM:
            raise MessageError(f"{key}: dimension {d!r:.20} outside {lo}..{MAX_DIM}")
        out.append(d)
    return tuple(out)


def _reject_constant(name: str) -> Any:
    raise MessageError(f"non-finite number {name} in JSON")


def loads_json(data: bytes, *, max_bytes: int = MAX_META_BYTES, what: str = "message") -> dict:
    """Parse an untrusted UTF-8 JSON object (NaN/Infinity rejected) or raise MessageError."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"{what}: expected bytes, got {type(data).__name__}")
    if len(data) > max_bytes:
        raise MessageError(f"{what}: {len(data)} bytes exceeds the maximum of {max_bytes}")
    try:
        obj = json.loads(bytes(data).decode("utf-8"), parse_constant=_reject_constant)
    except MessageError:
        raise
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError is a ValueError
        raise MessageError(f"{what}: not UTF-8 JSON ({exc.__class__.__name__}: {exc})"[:200]) from None
    if not isinstance(obj, dict):
        raise MessageError(f"{what}: expected a JSON object, got {type(obj).__name__}")
    return obj


def dumps_json(obj: Mapping) -> bytes:
    """Compact UTF-8 JSON; raises MessageError on NaN/inf (never sent)."""
    try:
        return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode("utf-8")
    except (ValueError, TypeError) as exc:
        raise MessageError(f"cannot encode: {exc}") from None


def pack_message(msg_type: int, meta: Mapping, payload: bytes) -> bytes:
    """Header + compact JSON ``meta`` + ``payload`` (the binary layout in the module docstring)."""
    m = dumps_json(meta)
    return HEADER.pack(MAGIC, msg_type, VERSION, 0, len(m), len(payload)) + m + payload


def unpack_message(data: Any, expect_type: int, max_bytes: int) -> tuple[dict, memoryview]:
    """Split untrusted bytes of a binary message into its meta and payload, header checked.

    Parameters
    ----------
    data : bytes-like
        The whole message.
    expect_type : int
        ``TYPE_FRAME`` or ``TYPE_CHAMFER``.
    max_bytes : int
        Largest message accepted.

    Returns
    -------
    meta : dict
        The decoded JSON meta (fields not yet validated: use :func:`meta_int` / :func:`meta_float`).
    payload : memoryview
        The bytes after the meta.

    Raises
    ------
    MessageError
        Wrong magic, type or version, sizes that do not add up, or meta that is not a JSON object.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"expected bytes, got {type(data).__name__}")
    view = memoryview(data).cast("B")
    if len(view) > max_bytes:
        raise MessageError(f"message of {len(view)} bytes exceeds the maximum of {max_bytes}")
    if len(view) < HEADER.size:
        raise MessageError(f"truncated header: {len(view)} < {HEADER.size} bytes")
    magic, mtype, version, _reserved, meta_len, payload_len = HEADER.unpack_from(view)
    if magic != MAGIC:
        raise MessageError(f"bad magic {bytes(magic)!r}")
    if mtype != expect_type:
        raise MessageError(f"type: expected {expect_type}, got {mtype}")
    if version != VERSION:
        raise MessageError(f"version: unsupported {version} (this build reads {VERSION})")
    if meta_len > MAX_META_BYTES:
        raise MessageError(f"meta_len {meta_len} exceeds {MAX_META_BYTES}")
    if HEADER.size + meta_len + payload_len != len(view):
        raise MessageError(
            f"length mismatch: header says {HEADER.size}+{meta_len}+{payload_len}, got {len(view)}")
    meta = loads_json(view[HEADER.size:HEADER.size + meta_len], what="meta")
    return meta, view[HEADER.size + meta_len:]


def peek_type(data: bytes) -> int | None:
    """The binary message type of ``data`` or None (no validation beyond the magic)."""
    if len(data) >= HEADER.size and bytes(data[:4]) == MAGIC:
        return data[4]
    return None


def _dtype(value: Any, key: str) -> np.dtype:
    if value not in DTYPES:
        raise MessageError(f"{key}: dtype must be one of {sorted(DTYPES)}, got {value!r:.40}")
    return np.dtype(DTYPES[value]).newbyteorder("<")


def _array(payload: memoryview, offset: int, dtype: np.dtype, shape: tuple[int, ...], key: str) -> np.ndarray:
    n = int(np.prod(shape)) * dtype.itemsize
    if offset + n > len(payload):
        raise MessageError(f"{key}: shape {shape} x {dtype.name} needs {n} bytes, payload too short")
    arr = np.frombuffer(payload, dtype=dtype, count=int(np.prod(shape)), offset=offset).reshape(shape)
    if dtype.kind == "f" and not np.isfinite(arr).all():
        raise MessageError(f"{key}: non-finite values")
    arr = arr.astype(dtype.newbyteorder("="), copy=True)
    arr.flags.writeable = False
    return arr


def _immutable(data) -> bool:
    """Whether ``data`` is ``bytes`` or a read-only memoryview of ``bytes`` (no one can change it)."""
    return isinstance(data, bytes) or (isinstance(data, memoryview) and data.readonly and isinstance(data.obj, bytes))


def _frozen(arr: np.ndarray) -> np.ndarray:
    if not (isinstance(arr, np.ndarray) and not arr.flags.writeable and arr.flags.c_contiguous):
        arr = np.array(arr, copy=True, order="C")
        arr.flags.writeable = False
    return arr


# ---------------------------------------------------------------------------------------------
# records


@dataclass(frozen=True)
class FrameMessage:
    """One camera frame. ``data`` is the raw pixel bytes (C order, ``shape`` (h, w[, c]), ``dtype``)
    when ``encoding == "raw"``, else the JPEG/PNG file bytes whose decoded image has ``shape``
    (:meth:`from_bytes` of ``bytes``: a read-only view of them; :meth:`image` of immutable raw data:
    a read-only view, not a copy)."""

    camera: str
    frame_id: int
    timestamp_ns: int
    encoding: str
    shape: tuple[int, ...]
    data: bytes | memoryview
    dtype: str = "uint8"

    TYPE = TYPE_FRAME

    @classmethod
    def from_image(cls, camera: str, frame_id: int, timestamp_ns: int, image: np.ndarray, *,
                   encoding: str = "raw", jpeg_quality: int = 90) -> "FrameMessage":
        """A frame message of one camera image.

        Parameters
        ----------
        camera : str
            Camera name (a short safe name).
        frame_id : int
            Trigger pulse number.
        timestamp_ns : int
            Capture time (ns).
        image : ndarray, shape (h, w) or (h, w, 3), uint8 or uint16
            BGR for colour.
        encoding : {"raw", "jpeg", "png"}
            ``raw`` sends the pixels as they are (little-endian).
        jpeg_quality : int
            1..100 for ``jpeg``.
        """
        image = np.ascontiguousarray(image)
        if encoding == "raw":
            data = image.astype(image.dtype.newbyteorder("<"), copy=False).tobytes()
        elif encoding in ("jpeg", "png"):
            import cv2

            params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if encoding == "jpeg" else []
            ok, buf = cv2.imencode(".jpg" if encoding == "jpeg" else ".png", image, params)
            if not ok:
                raise MessageError(f"camera {camera}: could not encode frame as {encoding}")
            data = buf.tobytes()
        else:
            raise MessageError(f"encoding: must be one of {ENCODINGS}, got {encoding!r}")
        return cls(camera, int(frame_id), int(timestamp_ns), encoding, tuple(image.shape), data,
                   image.dtype.name)

    @classmethod
    def wire_of_image(cls, camera: str, frame_id: int, timestamp_ns: int, image: np.ndarray, *,
                      encoding: str = "raw", jpeg_quality: int = 90) -> bytes:
        """``from_image(...).to_bytes()`` (same parameters, same bytes), copying a raw image's pixels
        once into the message instead of twice."""
        if encoding != "raw":
            return cls.from_image(camera, frame_id, timestamp_ns, image, encoding=encoding,
                                  jpeg_quality=jpeg_quality).to_bytes()
        image = np.ascontiguousarray(image)
        pixels = image.astype(image.dtype.newbyteorder("<"), copy=False)
        # a message around a view of the caller's array, packed at once and never kept
        return cls(camera, int(frame_id), int(timestamp_ns), "raw", tuple(image.shape),
                   memoryview(pixels).cast("B"), image.dtype.name).to_bytes()

    def image(self) -> np.ndarray:
        """Decoded image, shape ``self.shape``; MessageError if it does not decode to that shape."""
        if self.encoding == "raw":
            dtype = _dtype(self.dtype, "dtype")
            if _immutable(self.data) and (dtype.itemsize == 1 or dtype.isnative):  # a read-only view, no copy
                n = int(np.prod(self.shape))
                if n * dtype.itemsize != memoryview(self.data).nbytes:
                    raise MessageError(f"data: shape {self.shape} x {dtype.name} needs {n * dtype.itemsize} bytes, "
                                       f"got {memoryview(self.data).nbytes}")
                return np.frombuffer(self.data, dtype=dtype, count=n).reshape(self.shape)
            return _array(memoryview(self.data), 0, dtype, self.shape, "data")
        import cv2

        img = cv2.imdecode(np.frombuffer(self.data, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or tuple(img.shape) != self.shape:
            got = None if img is None else img.shape
            raise MessageError(f"camera {self.camera}: {self.encoding} data decodes to {got}, not {self.shape}")
        return img

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        meta = {"camera": self.camera, "frame_id": self.frame_id, "timestamp_ns": self.timestamp_ns,
                "encoding": self.encoding, "shape": list(self.shape), "dtype": self.dtype}
        return pack_message(TYPE_FRAME, meta, self.data)

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = MAX_BYTES) -> "FrameMessage":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        meta, payload = unpack_message(data, TYPE_FRAME, max_bytes)
        camera = check_name(meta.get("camera"))
        encoding = meta.get("encoding")
        if encoding not in ENCODINGS:
            raise MessageError(f"camera {camera}: encoding must be one of {ENCODINGS}, got {encoding!r:.40}")
        shape = _shape(meta.get("shape"), "shape", (2, 3))
        if len(shape) == 3 and shape[2] not in (1, 3, 4):
            raise MessageError(f"camera {camera}: shape channels must be 1, 3 or 4, got {shape[2]}")
        dtype = _dtype(meta.get("dtype", "uint8"), "dtype")
        if dtype.kind == "f":
            raise MessageError(f"camera {camera}: frames are integer images, got dtype {dtype.name}")
        if encoding == "raw" and int(np.prod(shape)) * dtype.itemsize != len(payload):
            raise MessageError(f"camera {camera}: shape {shape} x {dtype.name} != payload {len(payload)} bytes")
        if encoding != "raw" and len(payload) == 0:
            raise MessageError(f"camera {camera}: empty {encoding} payload")
        # immutable bytes in: keep a read-only view of their payload (a frame is ~1 MB: no copy)
        return cls(camera, meta_int(meta, "frame_id"), meta_int(meta, "timestamp_ns"), encoding, shape,
                   payload.toreadonly() if _immutable(data) else bytes(payload), dtype.name)


@dataclass(frozen=True)
class ChamferMessage:
    """Quantised distance images of one camera and frame.

    ``arrays``: ``((name, array), ...)``, each array 2-D ``(roi_h, roi_w)`` uint8/uint16 (or float32)
    covering the region of interest whose top-left pixel is ``roi_xy`` in an image of ``image_size``
    ``(w, h)``.  A stored value ``q`` means a distance of ``q / scale`` pixels, saturated at
    ``truncation_px``; arrays may be empty ``(0, 0)`` (nothing seen: truncation everywhere).
    ``attrs`` carries extra finite numbers (name -> float).  ``service.workers.components`` converts to and
    from ``segmentation.ChamferImages`` (arrays ``silhouette`` and ``edges``).
    """

    camera: str
    frame_id: int
    timestamp_ns: int
    image_size: tuple[int, int]
    roi_xy: tuple[int, int]
    truncation_px: float
    scale: float
    arrays: tuple[tuple[str, np.ndarray], ...]
    attrs: Mapping[str, float] = field(default_factory=dict)

    TYPE = TYPE_CHAMFER

    def __post_init__(self) -> None:
        object.__setattr__(self, "arrays", tuple((check_name(n, "array name"), _frozen(a)) for n, a in self.arrays))
        object.__setattr__(self, "attrs", MappingProxyType(dict(self.attrs)))

    def array(self, name: str) -> np.ndarray:
        """The read-only array called ``name`` (e.g. ``"silhouette"``, shape (h, w) of the ROI); KeyError if absent."""
        for n, a in self.arrays:
            if n == name:
                return a
        raise KeyError(f"camera {self.camera}: no array {name!r} (have {[n for n, _ in self.arrays]})")

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        specs, chunks = [], []
        for name, arr in self.arrays:
            if arr.dtype.name not in DTYPES or arr.ndim != 2:
                raise MessageError(f"array {name}: need a 2-D {sorted(DTYPES)} array, got {arr.dtype} {arr.shape}")
            specs.append({"name": name, "dtype": arr.dtype.name, "shape": list(arr.shape)})
            chunks.append(arr.astype(arr.dtype.newbyteorder("<"), copy=False).tobytes())
        meta = {"camera": self.camera, "frame_id": self.frame_id, "timestamp_ns": self.timestamp_ns,
                "image_size": list(self.image_size), "roi_xy": list(self.roi_xy),
                "truncation_px": self.truncation_px, "scale": self.scale, "arrays": specs,
                "attrs": dict(self.attrs)}
        return pack_message(TYPE_CHAMFER, meta, b"".join(chunks))

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = MAX_BYTES) -> "ChamferMessage":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        meta, payload = unpack_message(data, TYPE_CHAMFER, max_bytes)
        camera = check_name(meta.get("camera"))
        w, h = _shape(meta.get("image_size"), "image_size", (2,))
        roi = meta.get("roi_xy")
        if not isinstance(roi, list) or len(roi) != 2:
            raise MessageError(f"camera {camera}: roi_xy must be [x, y], got {roi!r:.40}")
        x0 = meta_int({"roi_x": roi[0]}, "roi_x", hi=w - 1)
        y0 = meta_int({"roi_y": roi[1]}, "roi_y", hi=h - 1)
        specs = meta.get("arrays")
        if not isinstance(specs, list) or not 0 < len(specs) <= 16:
            raise MessageError(f"camera {camera}: arrays must be a list of 1..16 specs")
        arrays, offset, names = [], 0, set()
        for spec in specs:
            if not isinstance(spec, dict):
                raise MessageError(f"camera {camera}: array spec must be an object")
            name = check_name(spec.get("name"), "array name")
            if name in names:
                raise MessageError(f"camera {camera}: duplicate array {name}")
            names.add(name)
            dtype = _dtype(spec.get("dtype"), f"{name}.dtype")
            rh, rw = _shape(spec.get("shape"), f"{name}.shape", (2,), allow_empty=True)
            if x0 + rw > w or y0 + rh > h:
                raise MessageError(f"camera {camera}: array {name} {rh}x{rw} at {x0},{y0} exceeds image {w}x{h}")
            arr = _array(payload, offset, dtype, (rh, rw), f"camera {camera} array {name}")
            offset += arr.nbytes
            arrays.append((name, arr))
        if offset != len(payload):
            raise MessageError(f"camera {camera}: arrays take {offset} bytes, payload has {len(payload)}")
        attrs = meta.get("attrs", {})
        if not isinstance(attrs, dict) or len(attrs) > 32:
            raise MessageError(f"camera {camera}: attrs must be an object of at most 32 numbers")
        attrs = {check_name(k, "attr name"): meta_float(attrs, k) for k in attrs}
        return cls(camera, meta_int(meta, "frame_id"), meta_int(meta, "timestamp_ns"), (w, h), (x0, y0),
                   meta_float(meta, "truncation_px"), meta_float(meta, "scale"), tuple(arrays), attrs)
