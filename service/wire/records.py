"""JSON wire records: the pose record, status/stats, lossless-mode credits and live-mode
have/demand notices.

All of them are UTF-8 JSON objects so that any zenoh client in any language can read them.  The pose
record is exactly the DESIGN.md object (``frame``, ``timestamp_ns``, ``ok``, ``model``, ``params``,
``joints`` {name: [x, y, z] metres, world frame}, ``rms_px``, ``iterations``, ``cameras``,
``latency_ms``; ``reason`` when ``ok`` is false; optional ``fit_ms``, ``fit_cpu_ms``, ``effort``,
``rejoin_ms``: the part of ``fit_ms`` the live fitter's cheap rejoin took in the set's own time,
``missing_cameras``: the names of the cameras a live set went on without; ``subject``: the name of the
subject body the pose is of; ``failed``: the quality-gate limits a not-ok fit failed, names such as
``"rms"``, ``"inside"``, ``"iou"``, ``"front_back"``, ``"limbs"``, ``"limb_colour"`` (a forearm or hand samples the trunk's, arms' or legs'
learned colour, not its own), ``"uncovered"`` (a camera's silhouette outline left unexplained beyond its usual
share); the gate's figures ``iou`` (silhouette IoU, when the
set's was rendered), ``inside_fraction`` and ``coverage``, numbers).  Status, credit, have and demand records carry
``"v": 1``.
Validation on receipt as in :mod:`service.wire.messages`: one :class:`MessageError` naming the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from service.wire.messages import MessageError, meta_float, meta_int, check_name, dumps_json, loads_json

POSE_MAX_BYTES = 1024 * 1024
STATUS_MAX_BYTES = 64 * 1024
RECORD_VERSION = 1
_MAX_PARAMS = 1024
_MAX_JOINTS = 128
_MAX_CAMERAS = 64
_MAX_FAILED = 16


def _finite_list(value: Any, key: str, *, length: int | None = None, max_len: int = _MAX_PARAMS) -> list[float]:
    if not isinstance(value, list) or len(value) > max_len or (length is not None and len(value) != length):
        raise MessageError(f"{key}: expected a list of {length or f'<= {max_len}'} numbers")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise MessageError(f"{key}: non-finite or non-numeric entry {v!r:.40}")
    return [float(v) for v in value]


def _check_version(obj: Mapping, what: str) -> None:
    if obj.get("v") != RECORD_VERSION:
        raise MessageError(f"{what}: version v={obj.get('v')!r:.20} unsupported (this build reads {RECORD_VERSION})")


@dataclass(frozen=True)
class PoseRecord:
    """One frame's pose (DESIGN.md pose record).  ``fields`` is the whole read-only JSON object."""

    frame: int
    timestamp_ns: int
    ok: bool
    fields: Mapping[str, Any] = field(repr=False)

    @classmethod
    def from_dict(cls, obj: Mapping[str, Any]) -> "PoseRecord":
        """Validate a pose object (from the tracker or the wire); MessageError names the key."""
        if not isinstance(obj, Mapping):
            raise MessageError(f"pose: expected an object, got {type(obj).__name__}")
        obj = dict(obj)
        frame = meta_int(obj, "frame")
        ts = meta_int(obj, "timestamp_ns")
        ok = obj.get("ok")
        if not isinstance(ok, bool):
            raise MessageError(f"ok: expected true/false, got {ok!r:.40}")
        if not ok and not isinstance(obj.get("reason"), str):
            raise MessageError("reason: a pose with ok=false must say why (string)")
        if "model" in obj and not isinstance(obj["model"], str):
            raise MessageError("model: expected a string")
        if "params" in obj:
            obj["params"] = _finite_list(obj["params"], "params")
        if "joints" in obj:
            joints = obj["joints"]
            if not isinstance(joints, dict) or len(joints) > _MAX_JOINTS:
                raise MessageError(f"joints: expected an object of at most {_MAX_JOINTS} joints")
            obj["joints"] = {check_name(k, "joint name"): _finite_list(v, f"joints.{k}", length=3)
                             for k, v in joints.items()}
        for key in ("rms_px", "latency_ms", "fit_ms", "fit_cpu_ms", "rejoin_ms", "iou", "inside_fraction", "coverage"):
            if obj.get(key) is not None:
                obj[key] = meta_float(obj, key)
        for key in ("iterations", "cameras"):
            if key in obj:
                meta_int(obj, key)
        if "subject" in obj and (not isinstance(obj["subject"], str) or not 0 < len(obj["subject"]) <= 200):
            raise MessageError("subject: expected the subject's name, a string of 1 to 200 characters")
        if "failed" in obj:
            failed = obj["failed"]
            if not isinstance(failed, list) or len(failed) > _MAX_FAILED:
                raise MessageError(f"failed: expected a list of at most {_MAX_FAILED} limit names")
            obj["failed"] = [check_name(c, "failed") for c in failed]
        if "missing_cameras" in obj:
            missing = obj["missing_cameras"]
            if not isinstance(missing, list) or len(missing) > _MAX_CAMERAS:
                raise MessageError(f"missing_cameras: expected a list of at most {_MAX_CAMERAS} camera names")
            obj["missing_cameras"] = [check_name(c, "missing_cameras") for c in missing]
        return cls(frame, ts, ok, MappingProxyType(obj))

    @property
    def joints(self) -> dict[str, np.ndarray]:
        """Joint name -> position (3,) metres, world frame."""
        return {k: np.asarray(v, float) for k, v in self.fields.get("joints", {}).items()}

    def get(self, key: str, default: Any = None) -> Any:
        """Field ``key`` of the record, or ``default``."""
        return self.fields.get(key, default)

    def replace(self, **updates: Any) -> "PoseRecord":
        """A new validated record with some fields changed (e.g. ``latency_ms``)."""
        return PoseRecord.from_dict({**self.fields, **updates})

    def to_dict(self) -> dict[str, Any]:
        """The record as a plain dict (a copy)."""
        return dict(self.fields)

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        return dumps_json(dict(self.fields))

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = POSE_MAX_BYTES) -> "PoseRecord":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        return cls.from_dict(loads_json(data, max_bytes=max_bytes, what="pose"))


@dataclass(frozen=True)
class StatusMessage:
    """Periodic health of one component: ``state`` and numeric ``stats`` (fps, drops, errors,
    queue_depth, latency_ms, ...: name -> finite number)."""

    component: str
    state: str
    timestamp_ns: int
    stats: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "stats", MappingProxyType(dict(self.stats)))

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        return dumps_json({"v": RECORD_VERSION, "component": self.component, "state": self.state,
                           "timestamp_ns": self.timestamp_ns, "stats": dict(self.stats)})

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = STATUS_MAX_BYTES) -> "StatusMessage":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        obj = loads_json(data, max_bytes=max_bytes, what="status")
        _check_version(obj, "status")
        stats = obj.get("stats", {})
        if not isinstance(stats, dict) or len(stats) > 64:
            raise MessageError("stats: expected an object of at most 64 numbers")
        stats = {check_name(k, "stat name"): meta_float(stats, k) for k in stats}
        return cls(check_name(obj.get("component"), "component"), check_name(obj.get("state"), "state"),
                   meta_int(obj, "timestamp_ns"), stats)


@dataclass(frozen=True)
class _ConsumerFrame:
    """``{"v": 1, "consumer": name, "frame_id": int}`` (credits and demands share this shape)."""

    consumer: str
    frame_id: int

    WHAT = "record"

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        return dumps_json({"v": RECORD_VERSION, "consumer": self.consumer, "frame_id": self.frame_id})

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = 4096):
        obj = loads_json(data, max_bytes=max_bytes, what=cls.WHAT)
        _check_version(obj, cls.WHAT)
        return cls(check_name(obj.get("consumer"), "consumer"), meta_int(obj, "frame_id"))


@dataclass(frozen=True)
class CreditMessage(_ConsumerFrame):
    """Lossless mode: ``consumer`` has finished every frame up to and including ``frame_id``."""

    WHAT = "credit"


DEMAND_MAX_ROIS = 64
"""At most this many cameras' regions of interest in one demand."""
_MAX_IMAGE_PX = 65536


def _check_rois(value: Any) -> dict[str, tuple[int, int, int, int]]:
    """``{camera: [x0, y0, x1, y1]}`` validated: names, at most :data:`DEMAND_MAX_ROIS`, integer
    half-open boxes with ``0 <= x0 < x1`` and ``0 <= y0 < y1`` within 65536 pixels."""
    if not isinstance(value, dict) or len(value) > DEMAND_MAX_ROIS:
        raise MessageError(f"rois: expected an object of at most {DEMAND_MAX_ROIS} cameras")
    out = {}
    for cam, box in value.items():
        name = check_name(cam, "rois camera")
        if (not isinstance(box, list) or len(box) != 4
                or any(isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= _MAX_IMAGE_PX for v in box)
                or not (box[0] < box[2] and box[1] < box[3])):
            raise MessageError(f"rois.{name}: expected [x0, y0, x1, y1] integers, 0 <= x0 < x1, 0 <= y0 < y1")
        out[name] = tuple(box)
    return out


@dataclass(frozen=True)
class DemandMessage(_ConsumerFrame):
    """Live mode: ``consumer`` (the tracker) wants frame ``frame_id`` of every camera segmented now
    (``contourcap/<studio>/demand/<consumer>``); segment workers segment nothing else.

    ``rois`` (optional, v1): camera name -> ``(x0, y0, x1, y1)``, the half-open pixel box where the
    body can be in that camera's frame (the tracker's predicted pose); a camera not named is
    segmented whole.  Wire: ``"rois": {camera: [x0, y0, x1, y1]}``, at most
    :data:`DEMAND_MAX_ROIS` cameras."""

    rois: Mapping[str, tuple[int, int, int, int]] | None = None

    WHAT = "demand"

    def __post_init__(self) -> None:
        if self.rois is not None:
            object.__setattr__(self, "rois", MappingProxyType(
                _check_rois({k: [int(v) for v in b] for k, b in self.rois.items()})))

    def to_bytes(self) -> bytes:
        """The wire bytes (see the class docstring)."""
        obj = {"v": RECORD_VERSION, "consumer": self.consumer, "frame_id": self.frame_id}
        if self.rois is not None:
            obj["rois"] = {k: list(b) for k, b in self.rois.items()}
        return dumps_json(obj)

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = 8192) -> "DemandMessage":
        """Decode and validate untrusted wire bytes; MessageError names the field at fault."""
        obj = loads_json(data, max_bytes=max_bytes, what=cls.WHAT)
        _check_version(obj, cls.WHAT)
        rois = _check_rois(obj["rois"]) if obj.get("rois") is not None else None
        return cls(check_name(obj.get("consumer"), "consumer"), meta_int(obj, "frame_id"), rois)


HAVE_MAX_FRAMES = 64


@dataclass(frozen=True)
class HaveMessage:
    """Live mode: the frame ids of ``camera`` that its segment worker holds (undecoded, ready to be
    segmented on demand), oldest first, at most :data:`HAVE_MAX_FRAMES`
    (``contourcap/<studio>/cam/<camera>/have``)."""

    camera: str
    frame_ids: tuple[int, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "frame_ids", tuple(int(f) for f in self.frame_ids))

    @property
    def newest(self) -> int | None:
        return max(self.frame_ids) if self.frame_ids else None

    def to_bytes(self) -> bytes:
        """The wire bytes (see the module docstring)."""
        return dumps_json({"v": RECORD_VERSION, "camera": self.camera, "frames": list(self.frame_ids)})

    @classmethod
    def from_bytes(cls, data: bytes, *, max_bytes: int = 4096) -> "HaveMessage":
        obj = loads_json(data, max_bytes=max_bytes, what="have")
        _check_version(obj, "have")
        frames = obj.get("frames")
        if not isinstance(frames, list) or len(frames) > HAVE_MAX_FRAMES:
            raise MessageError(f"frames: expected a list of at most {HAVE_MAX_FRAMES} frame ids")
        return cls(check_name(obj.get("camera")), tuple(meta_int({"frames": f}, "frames") for f in frames))
