"""bench/robustness.py's height-only vs calibrated summary (``--calibrate``, ``--calibrate-from``)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from robustness import _score, calibration_order, subject_body, summarise, truth_lengths  # noqa: E402
from tracker.body.subject import Subject, subject_toml  # noqa: E402


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


def test_calibration_take_runs_first_and_keeps_each_clips_index():
    clips = ["walk_turn", "crouch", "tpose_start", "cmu_walk"]
    assert calibration_order(clips, "tpose_start") == [(2, "tpose_start"), (0, "walk_turn"), (1, "crouch"),
                                                       (3, "cmu_walk")]
    assert calibration_order(clips, None) == list(enumerate(clips))


def test_held_out_figures_leave_out_the_calibration_takes():
    rng = np.random.default_rng(1)
    clips = []
    # subject 0: its tpose_start clip calibrated (own), crouch tracked with that body; subject 1 likewise
    for s in (0, 1):
        for name, before, after in (("tpose_start", 0.05, 0.02), ("crouch", 0.08, 0.06)):
            score, joints = _clip(rng, before, True)
            score_c, joints_c = _clip(rng, after, True)
            info = {"cpu_s": 30.0 + s, "adopted": True, "own": name == "tpose_start", "calibrate_from": "tpose_start",
                    "segment_lengths_m": {"thigh": (0.4, 0.41)[s]}}
            clips.append({**score, "subject": s, "clip": name, "cameras": 4, "joint_mm": joints, "ik_floor_mm": None,
                          "unprocessed": 0, "latencies_ms": [1.0], "pipeline_ms": [1.0],
                          "truth_lengths_m": {"thigh": 0.41},
                          "calibrated": {**score_c, "joint_mm": joints_c, "calibration": info}})
    out = summarise(clips)
    assert out["calibrate_from"] == "tpose_start" and out["clips_held_out"] == 2
    assert np.isclose(out["mpjpe_mm_mean_calibrated"], 40.0)  # all four clips: (20 + 60) / 2
    assert np.isclose(out["mpjpe_mm_mean_calibrated_held_out"], 60.0)  # the crouch clips only
    assert np.isclose(out["mpjpe_mm_mean_height_only_held_out"], 80.0)
    assert out["frames_calibrated_held_out"] == 60 and out["ok_percent_calibrated_held_out"] == 100.0
    # one calibration per subject counted, not one per clip tracked with it
    assert out["calibrations"] == 2 and out["calibration_cpu_s_total"] == 61.0
    assert [(b["subject"], b["clip"], b["segment_lengths_m"]["thigh"]) for b in out["calibration_bodies"]] == [
        (0, "tpose_start", 0.4), (1, "tpose_start", 0.41)]
    # --calibrate N (every clip its own calibration, no calibrate_from): no held-out figures
    for c in clips:
        c["calibrated"]["calibration"] = {"cpu_s": 30.0, "adopted": True}
    assert "calibrate_from" not in summarise(clips) and summarise(clips)["calibrations"] == 4


def test_a_calibration_tracks_other_takes_through_its_subject_file():
    subject = Subject("knossow40", 1.62, {"thigh": 0.43, "shank": 0.39}, "test", {"hip_width": 0.28},
                      {"thigh": 1.1})
    body = subject_body({"adopted": True, "subject_toml": subject_toml(subject)})
    want = subject.body()
    assert body.height_m == want.height_m
    assert np.allclose(body.offset, want.offset) and np.allclose(body.cones, want.cones)
    assert subject_body({"adopted": False, "subject_toml": subject_toml(subject)}) is None
    assert subject_body({"adopted": True}) is None


def test_truth_lengths_are_the_joint_distances():
    names = ("pelvis", "spine", "neck", "head", "left_shoulder", "left_elbow", "left_wrist", "right_shoulder",
             "right_elbow", "right_wrist", "left_hip", "left_knee", "left_ankle", "right_hip", "right_knee",
             "right_ankle")
    at = {"pelvis": (0, 0, 1.0), "neck": (0, 0, 1.5), "left_hip": (0, 0.08, 1.0), "left_knee": (0, 0.08, 0.6),
          "left_ankle": (0, 0.08, 0.2), "right_hip": (0, -0.08, 1.0), "right_knee": (0, -0.08, 0.56),
          "right_ankle": (0, -0.08, 0.16), "left_shoulder": (0, 0.2, 1.45), "left_elbow": (0, 0.5, 1.45),
          "left_wrist": (0, 0.75, 1.45), "right_shoulder": (0, -0.2, 1.45), "right_elbow": (0, -0.5, 1.45),
          "right_wrist": (0, -0.75, 1.45)}
    frame = np.array([at.get(n, (0.0, 0.0, 1.2)) for n in names], float)
    rot = np.array([[0.6, -0.8, 0.0], [0.8, 0.6, 0.0], [0.0, 0.0, 1.0]])  # lengths do not depend on heading
    truth = np.stack([frame, frame @ rot.T + [1.0, 2.0, 0.0]])
    out = truth_lengths(truth)
    assert np.isclose(out["thigh"], 0.42) and np.isclose(out["shank"], 0.4)  # (0.40 + 0.44) / 2, 0.40
    assert np.isclose(out["upper_arm"], 0.3) and np.isclose(out["forearm"], 0.25)
    assert np.isclose(out["pelvis_to_neck"], 0.5) and np.isclose(out["hip_width"], 0.16)
    assert np.isclose(out["shoulder_width"], 0.4)


@pytest.mark.parametrize("all_cameras", [False, True])
def test_calibrate_from_calibrates_each_subject_once_and_tracks_its_other_clips_with_it(monkeypatch, all_cameras):
    """``main --calibrate-from``'s wiring: per subject the MOTION clip runs first and it alone is calibrated
    (``calibrate_frames``; with ``--all-cameras`` at its first camera count), every other run of the subject
    gets that calibration, each clip keeps its camera count."""
    import robustness

    calls = []

    def run_clip(name, skeleton, s, n, *, calibrate_frames, calibration, **kw):
        calls.append((s, name, n, calibrate_frames, None if calibration is None else dict(calibration)))
        figures = dict.fromkeys(("mpjpe_mm", "ok", "frames", "mirrored", "mirrored_after", "false_ok", "false_alarm",
                                 "ik_floor_mm", "ms_per_frame_median", "cpu_s", "unprocessed"), 0)
        return {**figures, "calibrated": {**figures, "calibration": {"adopted": True, "text": f"s{s}"}}}

    monkeypatch.setattr(robustness, "run_clip", run_clip)
    monkeypatch.setattr(robustness, "machine_ref_ms", lambda: 1.0)
    monkeypatch.setattr(robustness, "warm_up_kernels", lambda method: 0.0)
    monkeypatch.setattr(robustness, "load_bvh", lambda path: None)
    monkeypatch.setattr(robustness, "summarise", lambda per_clip: {})
    monkeypatch.setattr(robustness, "_emit", lambda result, args: 0)
    monkeypatch.setattr(robustness, "_calibration_text", lambda info: "")
    printed = []
    monkeypatch.setattr("builtins.print", lambda *a, **k: printed.append(a))
    argv = ["--subject-ids", "1,2", "--clips", "walk_turn,crouch,tpose_start", "--cameras", "4,6",
            "--calibrate-from", "tpose_start"] + (["--all-cameras"] if all_cameras else [])
    assert robustness.main(argv) == 0
    per = 2 if all_cameras else 1
    assert len(calls) == 2 * 3 * per
    for s, start in ((1, 0), (2, 3 * per)):
        own, rest = calls[start], calls[start + 1:start + 3 * per]
        assert own[:2] == (s, "tpose_start") and own[3] == 100 and own[4] is None
        assert [c[1] for c in rest] == ["tpose_start"] * (per - 1) + ["walk_turn"] * per + ["crouch"] * per
        assert all(c[0] == s and c[3] == 0 and c[4]["text"] == f"s{s}" and c[4]["calibrate_from"] == "tpose_start"
                   and c[4]["source"]["subject"] == s for c in rest)
        if not all_cameras:  # clip j of subject s keeps cameras[(s + j) % 2] whatever the order it runs in
            assert [c[2] for c in calls[start:start + 3]] == [[4, 6][(s + 2) % 2], [4, 6][s % 2], [4, 6][(s + 1) % 2]]


def test_scene_options_reach_the_tracker_and_the_header(monkeypatch):
    """``--scene --scene-option NAME=VALUE``: the bench tracks with those ``SceneOptions`` (``contourcap track``'s
    default path) and says so in its header; ``--scene-option`` alone is refused."""
    import robustness
    from tracker.fitting.scene import SceneOptions

    figures = dict.fromkeys(("mpjpe_mm", "ok", "frames", "mirrored", "mirrored_after", "false_ok", "false_alarm",
                             "ik_floor_mm", "ms_per_frame_median", "cpu_s", "unprocessed"), 0)
    seen = {}
    monkeypatch.setattr(robustness, "TRACK_OPTIONS", dict(robustness.TRACK_OPTIONS))
    monkeypatch.setattr(robustness, "run_clip", lambda *a, **k: seen.setdefault("scene", robustness.TRACK_OPTIONS.get(
        "scene")) and dict(figures))
    monkeypatch.setattr(robustness, "machine_ref_ms", lambda: 1.0)
    monkeypatch.setattr(robustness, "warm_up_kernels", lambda method: 0.0)
    monkeypatch.setattr(robustness, "load_bvh", lambda path: None)
    monkeypatch.setattr(robustness, "summarise", lambda per_clip: {})
    monkeypatch.setattr(robustness, "_emit", lambda result, args: seen.update(header=result["scene"]) or 0)
    monkeypatch.setattr("builtins.print", lambda *a, **k: None)
    assert robustness.main(["--subject-ids", "0", "--clips", "walk_turn", "--scene", "--scene-option", "learn=false",
                            "--scene-option", "warmup_frames=5"]) == 0
    assert seen["scene"] == SceneOptions(learn=False, warmup_frames=5)
    assert seen["header"]["learn"] is False and seen["header"]["warmup_frames"] == 5
    with pytest.raises(SystemExit):
        robustness.main(["--scene-option", "learn=false"])
