"""Fuzzing every wire decoder and the pose-file reader (issue 16): any bytes give a typed error
(``MessageError`` / ``ExportError``) or a value, never another exception.

50 examples per test by default (derandomised in CI); ``pytest --fuzz-long`` runs 5000.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from service.wire.messages import ChamferMessage, FrameMessage, MessageError
from service.wire.records import CreditMessage, DemandMessage, HaveMessage, PoseRecord, StatusMessage
from tests.support.fuzz import hostile_bytes, json_objects

_rng = np.random.default_rng(5)
_IMAGE = _rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
POSE = PoseRecord.from_dict({"frame": 3, "timestamp_ns": 120_000_000, "ok": True, "model": "knossow40",
                             "params": [0.1] * 5, "joints": {"pelvis": [0.0, 0.1, 1.0]}, "rms_px": 1.5,
                             "iterations": 4, "cameras": 6, "latency_ms": 20.0})
SEEDS = {
    FrameMessage: FrameMessage.from_image("cam0", 7, 280_000_000, _IMAGE).to_bytes(),
    ChamferMessage: ChamferMessage("cam_1", 9, 10**12, (64, 48), (5, 6), 20.0, 8.0,
                                   (("edges", _rng.integers(0, 65535, (10, 12), dtype=np.uint16)),
                                    ("silhouette", _rng.integers(0, 255, (10, 12), dtype=np.uint8))),
                                   {"threshold": 12.5}).to_bytes(),
    PoseRecord: POSE.to_bytes(),
    StatusMessage: StatusMessage("track", "running", 5, {"fps": 3.0, "bad": 1.0}).to_bytes(),
    HaveMessage: HaveMessage("cam0", (5, 6, 7)).to_bytes(),
    DemandMessage: DemandMessage("track", 41).to_bytes(),
    CreditMessage: CreditMessage("track", 41).to_bytes(),
}
SLOW = settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def _decode(cls, data: bytes) -> None:
    try:
        msg = cls.from_bytes(data)
    except MessageError:
        return
    # a value: it must survive its own round trip
    assert cls.from_bytes(msg.to_bytes()).to_bytes() == msg.to_bytes()


@pytest.mark.parametrize("cls", list(SEEDS), ids=lambda c: c.__name__)
@SLOW
@given(data=st.data())
def test_decoders_raise_only_message_error(cls, data):
    _decode(cls, data.draw(hostile_bytes(SEEDS[cls])))


@pytest.mark.parametrize("cls,keys", [
    (PoseRecord, ("frame", "timestamp_ns", "ok", "model", "params", "joints", "rms_px", "iterations", "cameras",
                  "latency_ms", "fit_ms", "fit_cpu_ms", "rejoin_ms", "reason")),
    (StatusMessage, ("v", "component", "state", "timestamp_ns", "stats")),
    (HaveMessage, ("v", "camera", "frames")),
    (DemandMessage, ("v", "consumer", "frame_id")),
], ids=lambda c: getattr(c, "__name__", "keys"))
@SLOW
@given(data=st.data())
def test_json_records_with_wrong_types(cls, keys, data):
    obj = data.draw(json_objects(keys))
    try:
        text = json.dumps(obj).encode()
    except (ValueError, OverflowError):
        return
    _decode(cls, text)


@SLOW
@given(data=st.data())
def test_pose_file_reader(tmp_path_factory, data):
    from service.outputs.posefile import ExportError, read_pose_file

    good = POSE.to_bytes() + b"\n"
    body = data.draw(st.one_of(st.binary(max_size=512), st.lists(hostile_bytes(POSE.to_bytes()), max_size=4)
                               .map(lambda ls: b"\n".join(ls))))
    path = tmp_path_factory.mktemp("fuzz") / "p.jsonl"
    path.write_bytes(good + body)
    for skip_bad in (False, True):
        try:
            pf = read_pose_file(path, skip_bad=skip_bad)
        except ExportError:
            assert not skip_bad
            continue
        assert pf.records[0] == POSE and len(pf.records) + len(pf.skipped) >= 1
