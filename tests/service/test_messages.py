"""Wire messages: one contract for every type (round trip, garbage in -> only MessageError)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.wire.messages import HEADER, MAX_BYTES, ChamferMessage, FrameMessage, MessageError, peek_type
from service.wire.records import CreditMessage, PoseRecord, StatusMessage
from tests.support.messages import mutations as _mutations


def _frame(rng, encoding="raw"):
    img = rng.integers(0, 255, size=(24, 32, 3), dtype=np.uint8)
    return FrameMessage.from_image("cam0", 7, 123_456_789, img, encoding=encoding)


def _chamfer(rng):
    edges = rng.integers(0, 65535, size=(10, 12), dtype=np.uint16)
    sil = rng.integers(0, 255, size=(10, 12), dtype=np.uint8)
    return ChamferMessage("cam_1", 9, 10**12, (64, 48), (5, 6), 20.0, 8.0,
                          (("edges", edges), ("silhouette", sil)), {"threshold": 12.5})


def _pose(rng):
    return PoseRecord.from_dict({
        "frame": 12, "timestamp_ns": 400_000_000, "ok": True, "model": "knossow40",
        "params": rng.normal(size=40).tolist(),
        "joints": {"pelvis": [0.0, 0.1, 0.9], "head": [0.0, 0.05, 1.7]},
        "rms_px": 0.9, "iterations": 4, "cameras": 6, "latency_ms": 21.5})


SAMPLES = {
    "frame_raw": lambda rng: _frame(rng, "raw"),
    "frame_png": lambda rng: _frame(rng, "png"),
    "chamfer": _chamfer,
    "pose": _pose,
    "status": lambda rng: StatusMessage("segment-cam0", "running", 5, {"fps": 49.5, "drops": 3.0}),
    "credit": lambda rng: CreditMessage("track", 41),
}


def _equal(a, b) -> bool:
    if isinstance(a, ChamferMessage):
        return (a.camera, a.frame_id, a.image_size, a.roi_xy, dict(a.attrs)) == \
            (b.camera, b.frame_id, b.image_size, b.roi_xy, dict(b.attrs)) and all(
                na == nb and x.dtype == y.dtype and np.array_equal(x, y)
                for (na, x), (nb, y) in zip(a.arrays, b.arrays))
    if isinstance(a, PoseRecord):
        return a.to_dict() == b.to_dict()
    return a == b


@pytest.mark.parametrize("kind", sorted(SAMPLES))
def test_round_trip(kind, rng):
    msg = SAMPLES[kind](rng)
    back = type(msg).from_bytes(msg.to_bytes())
    assert _equal(msg, back)
    assert back.to_bytes() == msg.to_bytes()


def test_frame_pixels_survive(rng):
    img = rng.integers(0, 255, size=(24, 32, 3), dtype=np.uint8)
    for enc in ("raw", "png"):  # both lossless
        msg = FrameMessage.from_image("cam0", 1, 1, img, encoding=enc)
        assert np.array_equal(FrameMessage.from_bytes(msg.to_bytes()).image(), img)
    jpg = FrameMessage.from_image("cam0", 1, 1, np.full((16, 16), 128, np.uint8), encoding="jpeg")
    assert np.abs(FrameMessage.from_bytes(jpg.to_bytes()).image().astype(int) - 128).max() <= 2


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_raw_frame_of_immutable_bytes_is_a_read_only_view_and_of_mutable_bytes_a_copy(rng, dtype):
    img = rng.integers(0, 255, size=(24, 32, 3)).astype(dtype)
    wire = FrameMessage.from_image("cam0", 1, 1, img).to_bytes()
    view = FrameMessage.from_bytes(wire).image()
    assert np.array_equal(view, img) and not view.flags.writeable
    with pytest.raises(ValueError):
        view[0, 0, 0] = 1
    mutable = bytearray(wire)
    msg = FrameMessage.from_bytes(mutable)
    copy = msg.image()
    mutable[-1] ^= 0xFF  # the sender's buffer changes afterwards: the message and its image do not
    assert np.array_equal(copy, img) and np.array_equal(msg.image(), img)
    assert FrameMessage.from_bytes(msg.to_bytes()).to_bytes() == wire
    short = FrameMessage("cam0", 1, 1, "raw", (24, 32, 3), bytes(10), np.dtype(dtype).name)
    with pytest.raises(MessageError, match="bytes"):
        short.image()


@pytest.mark.parametrize("encoding, dtype, shape", [("raw", np.uint8, (24, 32, 3)), ("raw", np.uint16, (9, 7)),
                                                    ("png", np.uint8, (24, 32, 3)), ("jpeg", np.uint8, (16, 16))])
def test_wire_of_image_is_the_message_bytes(rng, encoding, dtype, shape):
    img = rng.integers(0, 255, size=shape).astype(dtype)
    strided = np.zeros((shape[0], 2 * shape[1]) + shape[2:], dtype)[:, ::2]  # not contiguous
    strided[...] = img
    for image in (strided, img):  # the last: the caller's own array
        wire = FrameMessage.wire_of_image("cam1", 7, 99, image, encoding=encoding, jpeg_quality=80)
        assert wire == FrameMessage.from_image("cam1", 7, 99, img, encoding=encoding, jpeg_quality=80).to_bytes()
    if encoding != "jpeg":  # lossless: the bytes hold the pixels as they were, not a view of the array
        before = img.copy()
        img[0] = 0
        np.testing.assert_array_equal(FrameMessage.from_bytes(wire).image(), before)


def test_pose_is_plain_design_json(rng):
    rec = _pose(rng)
    obj = json.loads(rec.to_bytes().decode())
    assert obj["frame"] == 12 and obj["joints"]["pelvis"] == [0.0, 0.1, 0.9]
    failed = PoseRecord.from_dict({"frame": 3, "timestamp_ns": 1, "ok": False, "reason": "no cameras"})
    assert PoseRecord.from_bytes(failed.to_bytes()).get("reason") == "no cameras"


@pytest.mark.parametrize("bad, word", [
    ({"frame": -1, "timestamp_ns": 0, "ok": True}, "frame"),
    ({"frame": 1, "timestamp_ns": 0, "ok": False}, "reason"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "joints": {"a": [1, 2]}}, "joints.a"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "joints": {"../x": [1, 2, 3]}}, "joint name"),
    ({"frame": 1, "timestamp_ns": 0, "ok": "yes"}, "ok"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "missing_cameras": ["\x1b[2J"]}, "missing_cameras"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "missing_cameras": "cam0"}, "missing_cameras"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "missing_cameras": ["c"] * 65}, "missing_cameras"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "rejoin_ms": "12"}, "rejoin_ms"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "iou": "0.9"}, "iou"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "inside_fraction": float("nan")}, "inside_fraction"),
    ({"frame": 1, "timestamp_ns": 0, "ok": True, "coverage": [1.0]}, "coverage"),
    ({"frame": 1, "timestamp_ns": 0, "ok": False, "reason": "x", "failed": "iou"}, "failed"),
    ({"frame": 1, "timestamp_ns": 0, "ok": False, "reason": "x", "failed": ["iou"] * 17}, "failed"),
    ({"frame": 1, "timestamp_ns": 0, "ok": False, "reason": "x", "failed": ["\x1b[2J"]}, "failed"),
])
def test_pose_validation_names_key(bad, word):
    with pytest.raises(MessageError, match=word):
        PoseRecord.from_dict(bad)


def test_non_finite_json_rejected():
    with pytest.raises(MessageError, match="non-finite"):
        PoseRecord.from_bytes(b'{"frame": 1, "timestamp_ns": 0, "ok": true, "rms_px": NaN}')


def test_binary_checks_name_the_problem(rng):
    good = _frame(rng).to_bytes()
    magic, t, v, r, ml, pl = HEADER.unpack_from(good)
    with pytest.raises(MessageError, match="version"):
        FrameMessage.from_bytes(HEADER.pack(magic, t, 2, r, ml, pl) + good[HEADER.size:])
    with pytest.raises(MessageError, match="type"):
        ChamferMessage.from_bytes(good)
    with pytest.raises(MessageError, match="maximum"):
        FrameMessage.from_bytes(good, max_bytes=len(good) - 1)
    meta = json.loads(good[HEADER.size:HEADER.size + ml])
    meta["shape"] = [24, 32, 4]
    m = json.dumps(meta).encode()
    with pytest.raises(MessageError, match="payload"):
        FrameMessage.from_bytes(HEADER.pack(magic, t, v, r, len(m), pl) + m + good[HEADER.size + ml:])
    meta["shape"], meta["camera"] = [24, 32, 3], "../../etc"
    m = json.dumps(meta).encode()
    with pytest.raises(MessageError, match="camera"):
        FrameMessage.from_bytes(HEADER.pack(magic, t, v, r, len(m), pl) + m + good[HEADER.size + ml:])
    assert peek_type(good) == FrameMessage.TYPE and peek_type(b"xx") is None


def test_chamfer_roi_must_fit_image(rng):
    msg = ChamferMessage("cam0", 1, 1, (16, 16), (10, 10), 20.0, 1.0,
                         (("d", np.zeros((8, 8), np.uint8)),))
    with pytest.raises(MessageError, match="exceeds image"):
        ChamferMessage.from_bytes(msg.to_bytes())



@pytest.mark.parametrize("kind", sorted(SAMPLES))
def test_fuzz_only_message_error(kind):
    rng = np.random.default_rng(2024)
    proto = SAMPLES[kind](rng)
    data = proto.to_bytes()
    decoders = [FrameMessage, ChamferMessage, PoseRecord, StatusMessage, CreditMessage]
    accepted = rejected = 0
    for _ in range(150):
        for bad in _mutations(data, rng):
            for cls in decoders:
                try:
                    out = cls.from_bytes(bad)
                except MessageError:
                    rejected += 1
                else:
                    accepted += 1
                    if isinstance(out, FrameMessage):
                        try:
                            out.image()
                        except MessageError:
                            pass
    assert rejected > 0
    assert accepted < rejected


def test_oversized_rejected_before_parsing():
    with pytest.raises(MessageError, match="maximum"):
        FrameMessage.from_bytes(b"\0" * (MAX_BYTES + 1))
    with pytest.raises(MessageError, match="maximum"):
        PoseRecord.from_bytes(b" " * (2 * 1024 * 1024))
