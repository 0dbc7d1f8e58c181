"""BVH export: parse it back (tracker.synthetic.bvh), check channel and frame counts, and that the BVH's forward
kinematics reproduces the body model's part2world transforms for random poses."""

from __future__ import annotations

import numpy as np
import pytest

from service.export import ExportError, read_pose_records, write_bvh, write_pose_records
from service.wire.records import PoseRecord

model_mod = pytest.importorskip("tracker.body.model")
bvh_mod = pytest.importorskip("tracker.synthetic.bvh")
kin = pytest.importorskip("tracker.body.kinematics")


def _records(model, rng, n=6):
    out = []
    for k in range(n):
        p = model.random_params(rng, fraction=0.5)
        p[:3] = rng.normal(size=3) * 0.5
        out.append(PoseRecord.from_dict({"frame": k, "timestamp_ns": k * 40_000_000, "ok": True,
                                         "model": model.name, "params": p.tolist()}))
    out[3] = PoseRecord.from_dict({"frame": 3, "timestamp_ns": 3 * 40_000_000, "ok": False, "reason": "lost"})
    return out


@pytest.mark.parametrize("name", ["knossow40", "knossow54"])
def test_bvh_round_trip_matches_model(tmp_path, rng, name):
    model = model_mod.load_model(name)
    records = _records(model, rng)
    jsonl = tmp_path / "poses.jsonl"
    assert write_pose_records(jsonl, records) == len(records)
    back = read_pose_records(jsonl)
    out = write_bvh(tmp_path / "out.bvh", model, back, up="z")
    assert (out.frames, out.repeated, out.joints) == (6, 1, model.n_parts)
    assert out.fps == pytest.approx(25.0)
    bvh = bvh_mod.load_bvh(tmp_path / "out.bvh")
    moving = [c for c in bvh.channels if c]
    assert len(moving) == model.n_parts and len(moving[0]) == 6 and all(len(c) == 3 for c in moving[1:])
    assert bvh.motion.shape == (6, 6 + 3 * (model.n_parts - 1)) and bvh.fps == pytest.approx(25.0)
    P, R = bvh_mod.bvh_forward(bvh)
    R0 = kin.forward(model, model.zero()).rotation  # BVH bones are T-pose relative (tracker.joint_frames)
    for f, rec in enumerate(records):
        src = records[2] if f == 3 else rec  # frame 3 was lost: the previous pose is repeated
        pose = kin.forward(model, np.asarray(src.get("params")))
        idx = [bvh.index(n) for n in model.part_names]
        np.testing.assert_allclose(P[f, idx], pose.translation, atol=2e-5)  # 6-decimal file
        np.testing.assert_allclose(R[f, idx] @ R0, pose.rotation, atol=1e-5)


def test_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"frame": 1, "timestamp_ns": 0, "ok": true}\n{"frame": "x"}\n')
    with pytest.raises(ExportError, match=r"bad.jsonl:2: frame"):
        read_pose_records(bad)
    model = model_mod.load_model("knossow40")
    only_lost = [PoseRecord.from_dict({"frame": 0, "timestamp_ns": 0, "ok": False, "reason": "x"})]
    with pytest.raises(ExportError, match="no ok pose"):
        write_bvh(tmp_path / "o.bvh", model, only_lost)


def test_bvh_y_up_and_frame_id_gaps_keep_time(tmp_path, rng):
    """Y up by default ((x, y, z) -> (x, z, -y)); frame ids 13, 14, 18, 19 give 7 BVH frames at the
    session's rate, the missing ids holding the previous pose."""
    model = model_mod.load_model("knossow40")
    ids = [13, 14, 18, 19]
    params = [model.random_params(rng, fraction=0.5) for _ in ids]
    records = [PoseRecord.from_dict({"frame": k, "timestamp_ns": k * 33_333_333, "ok": True, "model": model.name,
                                     "params": p.tolist()}) for k, p in zip(ids, params)]
    out = write_bvh(tmp_path / "y.bvh", model, records)
    assert (out.frames, out.repeated, out.first_frame, out.up) == (7, 3, 13, "y")
    assert out.fps == pytest.approx(30.0, rel=1e-6)
    bvh = bvh_mod.load_bvh(tmp_path / "y.bvh")
    assert bvh.n_frames == 7 and bvh.fps == pytest.approx(30.0, rel=1e-6)
    P, _ = bvh_mod.bvh_forward(bvh)
    idx = [bvh.index(n) for n in model.part_names]
    src = [0, 1, 1, 1, 1, 2, 3]  # frames 15-17 hold frame 14
    for row, k in enumerate(src):
        t = kin.forward(model, params[k]).translation
        np.testing.assert_allclose(P[row, idx], np.c_[t[:, 0], t[:, 2], -t[:, 1]], atol=2e-5)
    with pytest.raises(ExportError, match="frame ids must increase"):
        write_bvh(tmp_path / "bad.bvh", model, records[::-1])
