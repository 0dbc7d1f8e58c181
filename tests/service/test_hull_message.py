"""The coloured hull on the wire (``service.wire.hull``): round trip, bounds, garbage in -> only MessageError."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.wire.hull import HULL_MAX_VOXELS, HullMessage, hull_message
from service.wire.messages import HEADER, ChamferMessage, FrameMessage, MessageError
from service.wire.records import PoseRecord
from tests.support.messages import mutations


def _hull(rng, n=50):
    return HullMessage(11, 123_456, rng.uniform(-1, 2, (n, 3)), rng.choice([0.03, 0.06, 0.12], n),
                       rng.uniform(0, 255, (n, 3)), 0.03)


def test_round_trip_is_exact(rng):
    msg = _hull(rng)
    back = HullMessage.from_bytes(msg.to_bytes())
    assert (back.frame_id, back.timestamp_ns, back.count, back.min_voxel_m) == (11, 123_456, 50, 0.03)
    assert np.array_equal(back.centres, msg.centres) and np.array_equal(back.sizes, msg.sizes)
    assert np.array_equal(back.colours, msg.colours) and back.colours.dtype == np.uint8
    assert np.array_equal(back.rgb(), msg.colours[:, ::-1])
    assert back.to_bytes() == msg.to_bytes()
    assert len(msg.to_bytes()) < 200 + 19 * 50  # 19 bytes per voxel
    empty = HullMessage.from_bytes(HullMessage(0, 0, np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), 0.03).to_bytes())
    assert empty.count == 0


def test_validation_names_the_field(rng):
    good = _hull(rng, 4).to_bytes()
    magic, t, v, r, ml, pl = HEADER.unpack_from(good)
    meta = json.loads(good[HEADER.size:HEADER.size + ml])
    payload = good[HEADER.size + ml:]

    def with_meta(**kw):
        m = json.dumps({**meta, **kw}).encode()
        return HEADER.pack(magic, t, v, r, len(m), pl) + m + payload

    with pytest.raises(MessageError, match="count"):
        HullMessage.from_bytes(with_meta(count=5))
    with pytest.raises(MessageError, match="count"):
        HullMessage.from_bytes(with_meta(count=HULL_MAX_VOXELS + 1))
    with pytest.raises(MessageError, match="min_voxel_m"):
        HullMessage.from_bytes(with_meta(min_voxel_m=0))
    with pytest.raises(MessageError, match="type"):
        HullMessage.from_bytes(FrameMessage.from_image("cam0", 1, 1, np.zeros((4, 4), np.uint8)).to_bytes())
    nan = bytearray(good)
    nan[HEADER.size + ml:HEADER.size + ml + 4] = np.float32(np.nan).tobytes()
    with pytest.raises(MessageError, match="finite"):
        HullMessage.from_bytes(bytes(nan))
    with pytest.raises(MessageError, match="centres"):
        HullMessage(0, 0, np.zeros((3, 2)), np.ones(3), np.zeros((3, 3)), 0.03)
    with pytest.raises(MessageError, match="maximum"):
        n = HULL_MAX_VOXELS + 1
        HullMessage(0, 0, np.zeros((n, 3)), np.full(n, 0.03), np.zeros((n, 3)), 0.03)


def test_hull_message_keeps_the_largest_cubes_within_the_bound(rng):
    from tracker.blobs import ColourHull

    n = 40
    sizes = np.r_[np.full(10, 0.12), np.full(30, 0.03)]
    hull = ColourHull(rng.uniform(-1, 1, (n, 3)), sizes, np.ones(n, bool), np.array([[-1.0] * 3, [1.0] * 3]), 0.03,
                      colours=rng.uniform(0, 255, (n, 2, 3)).astype(np.float32), camera_names=("a", "b"))
    msg = hull_message(3, 4, hull, max_voxels=25)
    assert msg.count == 25 and msg.dropped == 15 and np.sum(msg.sizes > 0.1) == 10
    full = hull_message(3, 4, hull)
    assert full.dropped == 0 and np.allclose(full.colours, np.rint(hull.colours.mean(1)), atol=1)


def test_fuzz_only_message_error():
    rng = np.random.default_rng(2025)
    data = _hull(rng, 30).to_bytes()
    accepted = rejected = 0
    for _ in range(200):
        for bad in mutations(data, rng):
            for cls in (HullMessage, FrameMessage, ChamferMessage, PoseRecord):
                try:
                    cls.from_bytes(bad)
                except MessageError:
                    rejected += 1
                else:
                    accepted += 1
    assert rejected > 0 and accepted < rejected
