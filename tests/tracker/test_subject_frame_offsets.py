"""bench/subject_frame_offsets.py: offsets expressed in the subject's pelvis heading frame."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from subject_frame_offsets import heading_frame, offsets  # noqa: E402


def test_known_body_frame_offset_is_recovered_at_random_headings():
    rng = np.random.default_rng(3)
    reference, poses = [], []
    shift = np.array([0.01, -0.04, 0.02])  # 10 mm to the left, 40 mm behind, 20 mm up
    for k in range(20):
        yaw = rng.uniform(-np.pi, np.pi)
        fwd, left = np.array([np.cos(yaw), np.sin(yaw), 0.0]), np.array([-np.sin(yaw), np.cos(yaw), 0.0])
        pelvis = rng.normal(0.0, 1.0, 3)
        ref = {"left_hip": pelvis + 0.1 * left, "right_hip": pelvis - 0.1 * left,
               "neck": pelvis + [0.0, 0.0, 0.5] + rng.normal(0.0, 0.02, 3)}
        ours = dict(ref, neck=ref["neck"] + shift[0] * left + shift[1] * fwd + [0.0, 0.0, shift[2]])
        reference.append({"frame": k, "joints": {n: v.tolist() for n, v in ref.items()}})
        poses.append({"frame": k, "joints": {n: v.tolist() for n, v in ours.items()}})
    out = offsets(reference, poses)
    assert out["neck"]["n"] == 20
    assert np.allclose([out["neck"][a] for a in ("side", "fwd", "up")], 1e3 * shift, atol=0.11)
    assert np.allclose([out["left_hip"][a] for a in ("side", "fwd", "up")], 0.0, atol=0.11)


def test_heading_frame_faces_forward():
    B = heading_frame([0.0, 0.1, 0.9], [0.0, -0.1, 0.9])  # left along +y: the subject faces +x
    assert np.allclose(B, [[0, 1, 0], [1, 0, 0], [0, 0, 1]])


def _names():
    from tracker.body.model import JOINT_NAMES
    return list(JOINT_NAMES)


def _body(rng, n):
    """n frames of 16 joints at random places and headings, hips ±0.1 m along the subject's left."""
    names = _names()
    yaw = rng.uniform(-np.pi, np.pi, n)
    left = np.stack([-np.sin(yaw), np.cos(yaw), np.zeros(n)], axis=1)
    fwd = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n)], axis=1)
    truth = rng.normal(0.0, 0.3, (n, 16, 3)) + rng.normal(0.0, 2.0, (n, 1, 3))
    pelvis = truth[:, names.index("pelvis")]
    truth[:, names.index("left_hip")] = pelvis + 0.1 * left
    truth[:, names.index("right_hip")] = pelvis - 0.1 * left
    truth[:, names.index("neck")] = pelvis + [0.0, 0.0, 0.5]
    return truth, left, fwd


def test_decompose_splits_a_body_frame_offset_from_scatter():
    rng = np.random.default_rng(5)
    names = _names()
    truth, left, fwd = _body(rng, 200)
    pred = truth.copy()
    w = names.index("left_wrist")
    pred[:, w] += -0.03 * fwd + 0.02 * left  # 30 mm behind, 20 mm to the left: a definition offset
    e = names.index("right_elbow")
    pred[:, e] += rng.normal(0.0, 0.01, (200, 3))  # scatter only
    pred[:50] = np.nan  # frames without a pose are skipped
    from subject_frame_offsets import decompose
    out = decompose(pred, truth, names)
    assert out["frames"] == 150
    wj, ej = out["joints"]["left_wrist"], out["joints"]["right_elbow"]
    assert np.allclose([wj["offset_side"], wj["offset_fwd"], wj["offset_up"]], [20.0, -30.0, 0.0], atol=0.11)
    assert wj["rest"] < 0.1 and np.isclose(wj["error"], np.hypot(20, 30), atol=0.11) and wj["lost"] == 0
    assert ej["offset"] < 3.0 and 10.0 < ej["rest"] < 20.0
    assert out["joints"]["head"]["error"] == 0.0
    assert abs(out["torso"]["yaw_deg_abs"]) < 1e-6 and abs(out["torso"]["lean_fwd_deg_mean"]) < 1e-6


def test_decompose_reads_the_torso_yaw_lean_and_lost_stretches():
    rng = np.random.default_rng(6)
    names = _names()
    truth, left, fwd = _body(rng, 100)
    pred = truth.copy()
    pel, li, ri, nk = (names.index(j) for j in ("pelvis", "left_hip", "right_hip", "neck"))
    a = np.radians(10.0)  # the fit's hip line turned 10 deg to the subject's left (counter-clockwise)
    pred[:, li] = truth[:, pel] + 0.1 * (np.cos(a) * left - np.sin(a) * fwd)
    pred[:, ri] = truth[:, pel] - 0.1 * (np.cos(a) * left - np.sin(a) * fwd)
    b = np.radians(8.0)  # the trunk leant 8 deg forward
    pred[:, nk] = truth[:, pel] + 0.5 * (np.cos(b) * np.array([0.0, 0.0, 1.0]) + np.sin(b) * fwd)
    w = names.index("right_wrist")
    pred[:20, w] += 0.4 * fwd[:20]  # an arm lost for 20 of 100 frames
    from subject_frame_offsets import decompose
    out = decompose(pred, truth, names)
    assert np.isclose(out["torso"]["yaw_deg_mean"], 10.0, atol=0.01)
    assert np.isclose(out["torso"]["lean_fwd_deg_mean"], 8.0, atol=0.01)
    assert abs(out["torso"]["lean_side_deg_mean"]) < 0.01 and abs(out["torso"]["pelvis_up_mm_mean"]) < 0.01
    assert np.isclose(out["joints"]["right_wrist"]["lost"], 80.0, atol=0.11)
    assert np.isclose(out["joints"]["right_wrist"]["error"], 80.0, atol=0.11)
