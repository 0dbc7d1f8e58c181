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
