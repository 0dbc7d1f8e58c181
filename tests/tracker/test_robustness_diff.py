"""bench/robustness_diff.py: the paired comparison of two robustness results and its input checks."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from robustness_diff import bootstrap_interval, compare, load_clips, main  # noqa: E402


def _result(mpjpe, *, ok=60, false_ok=1, false_alarm=2, mirrored_after=0, calibrated=None) -> dict:
    clips = []
    for i, mm in enumerate(mpjpe):
        clip = {"subject": i // 6, "clip": f"m{i % 6}", "cameras": 4 + 2 * (i % 2), "mpjpe_mm": float(mm),
                "frames": 75, "ok": ok, "false_ok": false_ok, "false_alarm": false_alarm,
                "mirrored_after": mirrored_after, "posed_after": 45}
        if calibrated is not None:
            clip["calibrated"] = {**{k: clip[k] for k in ("frames", "ok", "false_ok", "false_alarm",
                                                         "mirrored_after", "posed_after")},
                                  "mpjpe_mm": float(calibrated[i])}
        clips.append(clip)
    return {"per_clip": clips}


def _write(tmp_path, name, data) -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_consistent_shift_is_told_from_noise(tmp_path, seed):
    rng = np.random.default_rng(seed)
    a = rng.uniform(35.0, 120.0, 36)
    noise = rng.normal(0.0, 10.0, 36)
    pa = _write(tmp_path, "a.json", _result(a))
    shifted = load_clips(_write(tmp_path, "b.json", _result(a - 5.0 + 0.5 * rng.normal(size=36))))
    noisy = load_clips(_write(tmp_path, "c.json", _result(a + noise - noise.mean())))
    out = compare(load_clips(pa), shifted, seed=seed)
    lo, hi = out["mpjpe_mm_diff_ci95"]
    assert out["clips"] == 36 and -5.5 < lo <= hi < -4.5  # near the shift (sd 0.5 per clip), far from 0
    assert out["better"] == 36 and out["worse"] == 0
    lo, hi = compare(load_clips(pa), noisy, seed=seed)["mpjpe_mm_diff_ci95"]
    assert lo < 0.0 < hi  # a zero-mean reshuffle is not a change
    assert hi - lo > 2.0  # ... and its interval is as wide as the noise says (sd 10 over 36 clips: ~6.5 mm)


def test_bootstrap_interval_of_a_constant_and_of_nothing():
    assert bootstrap_interval(np.full(10, 2.5)) == (2.5, 2.5)
    assert all(np.isnan(bootstrap_interval(np.array([]))))


def test_pooled_counts_and_unpaired_clips(tmp_path):
    a = load_clips(_write(tmp_path, "a.json", _result([40.0, 50.0, 60.0], false_ok=2, mirrored_after=1)))
    b = load_clips(_write(tmp_path, "b.json", _result([40.0, 45.0], ok=70, false_alarm=0)))
    out = compare(a, b)
    assert (out["clips"], out["only_in_a"], out["only_in_b"]) == (2, 1, 0)
    assert out["a"]["false_ok_frames"] == 4 and out["a"]["mirrored_after_frames"] == 2
    assert out["a"]["mirrored_after_percent"] == pytest.approx(100.0 * 2 / 90)
    assert out["b"]["ok_percent"] == pytest.approx(100.0 * 140 / 150) and out["b"]["false_alarm_frames"] == 0
    assert out["mpjpe_mm_diff_mean"] == pytest.approx(-2.5) and (out["better"], out["worse"]) == (1, 0)
    assert [r["clip"] for r in out["most_better"]] == ["s0 m1 c6"] and out["most_worse"] == []


def test_calibrated_tracks_are_compared_when_asked(tmp_path):
    a = _write(tmp_path, "a.json", _result([50.0, 60.0], calibrated=[45.0, 55.0]))
    b = _write(tmp_path, "b.json", _result([50.0, 60.0], calibrated=[40.0, 50.0]))
    assert compare(load_clips(a), load_clips(b))["mpjpe_mm_diff_mean"] == 0.0
    assert compare(load_clips(a, calibrated=True), load_clips(b, calibrated=True))["mpjpe_mm_diff_mean"] == -5.0


@pytest.mark.parametrize("data, key", [
    ({"clips": []}, "'per_clip'"),
    ({"per_clip": [{"subject": "0", "clip": "walk", "cameras": 4}]}, "'subject'"),
    ({"per_clip": [{"subject": 0, "clip": "walk", "cameras": 4, "mpjpe_mm": float("nan")}]}, "'mpjpe_mm'"),
    ({"per_clip": [{"subject": 0, "clip": "walk", "cameras": 4, "mpjpe_mm": 40.0, "frames": -1}]}, "'frames'"),
])
def test_a_bad_file_is_refused_naming_the_file_and_key(tmp_path, data, key, capsys):
    path = _write(tmp_path, "bad.json", data)
    with pytest.raises(ValueError, match=key) as err:
        load_clips(path)
    assert str(path) in str(err.value)
    good = _write(tmp_path, "good.json", _result([40.0]))
    assert main([str(good), str(path)]) == 2
    assert str(path) in capsys.readouterr().err


def test_the_command_prints_json(tmp_path, capsys):
    a = _write(tmp_path, "a.json", _result([40.0, 50.0]))
    b = _write(tmp_path, "b.json", _result([41.0, 48.0]))
    assert main([str(a), str(b), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["clips"] == 2 and out["mpjpe_mm_diff_mean"] == pytest.approx(-0.5)
    (tmp_path / "notjson.json").write_text("{")
    assert main([str(a), str(tmp_path / "notjson.json")]) == 2


def test_runs_made_with_other_settings_are_said_to_differ(tmp_path, capsys):
    """A result without ``smooth_s`` was not smoothed: against a smoothed run the settings are named."""
    a = _write(tmp_path, "a.json", {**_result([40.0, 50.0]), "retrack": True, "clip_budget_s": 60.0})
    b = _write(tmp_path, "b.json", {**_result([41.0, 48.0]), "retrack": True, "clip_budget_s": 60.0,
                                     "smooth_s": 1 / 6, "calibrate_from": "tpose_start"})
    assert main([str(a), str(b), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["settings_differ"] == {"smooth_s": [0.0, 1 / 6],
                                                                      "calibrate_from": [None, "tpose_start"]}
    assert main([str(a), str(a)]) == 0
    assert "settings differ" not in capsys.readouterr().out
    assert main([str(a), str(b)]) == 0
    assert "settings differ (A vs B): smooth_s 0.0 vs 0.16" in capsys.readouterr().out
