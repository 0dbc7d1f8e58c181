"""bench/robustness.py's height-only vs calibrated summary (``--calibrate``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from robustness import _score, summarise  # noqa: E402


def _clip(rng, offset_m: float, ok: bool) -> tuple[dict, dict]:
    truth = rng.normal(0.0, 0.3, (30, 16, 3))
    records = [{"frame": k, "ok": ok, "joints": dict(zip(
        ("pelvis", "spine", "neck", "head", "left_shoulder", "left_elbow", "left_wrist", "right_shoulder",
         "right_elbow", "right_wrist", "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee",
         "right_ankle"), (truth[k] + [offset_m, 0.0, 0.0]).tolist()))} for k in range(30)]
    score, joint_mm, _ = _score(records, truth, 30.0)
    return score, joint_mm


def test_summary_gives_both_models_side_by_side():
    rng = np.random.default_rng(0)
    clips = []
    for s, (before, after) in enumerate(((0.06, 0.03), (0.10, 0.05))):
        score, joints = _clip(rng, before, True)
        score_c, joints_c = _clip(rng, after, True)
        clips.append({**score, "subject": s, "joint_mm": joints, "ik_floor_mm": None, "unprocessed": 0,
                      "latencies_ms": [1.0], "pipeline_ms": [1.0],
                      "calibrated": {**score_c, "joint_mm": joints_c,
                                     "calibration": {"cpu_s": 10.0 + s, "adopted": s == 1}}})
    out = summarise(clips)
    assert out["mpjpe_mm_mean_height_only"] == out["mpjpe_mm_mean"]
    assert np.isclose(out["mpjpe_mm_mean_height_only"], 80.0) and np.isclose(out["mpjpe_mm_mean_calibrated"], 40.0)
    assert np.isclose(out["mpjpe_mm_worst_clip_calibrated"], 50.0)
    assert out["joint_mm_height_only"]["left_knee"] == 80.0 and out["joint_mm_calibrated"]["head"] == 40.0
    assert out["calibration_cpu_s_median"] == 10.5
    assert out["calibration_adopted_percent"] == 50.0
    assert "mpjpe_mm_mean_calibrated" not in summarise([{k: v for k, v in c.items() if k != "calibrated"}
                                                       for c in clips])
