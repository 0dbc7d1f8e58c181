"""``service.smoothed``: the offline smoothing of a stream of pose records.  Streamed it equals the whole take
smoothed at once; records keep their verdicts and order; a frame without a pose, a change of the reported
front/back hypothesis and a jump are never crossed; the look-ahead is the window's half; an interrupt still
yields every record read."""

from __future__ import annotations

import numpy as np
import pytest

from service.smoothed import MAX_JOINT_SPEED_MPS, pose_breaks, smoothed_records, window_half
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.body.window import segment_halves, smooth_poses

MODEL = load_model("knossow40")
FPS = 30.0


def _take(seed: int, n: int = 40, noise: float = 0.01) -> list[dict]:
    """Pose records of a slowly moving body with jittery parameters; some not ok, one without a pose."""
    rng = np.random.default_rng(seed)
    p0 = MODEL.random_params(rng, fraction=0.3)
    t = np.arange(n)[:, None] / FPS
    P = p0 + 0.1 * np.sin(2 * np.pi * 0.5 * t + rng.uniform(0, 6, MODEL.n_params)) + rng.normal(0, noise, (n, MODEL.n_params))
    P = np.clip(P, MODEL.lower, MODEL.upper)
    recs = []
    for k, p in enumerate(P):
        J = joint_centre_array(MODEL, forward(MODEL, p))
        ok = bool(rng.random() < 0.8)
        rec = {"frame": k, "timestamp_ns": int(k * 1e9 / FPS), "model": MODEL.name, "ok": ok,
               "params": [float(v) for v in p], "joints": {m: J[i].tolist() for i, m in enumerate(MODEL.joint_names)},
               "iou": float(rng.random()), "rms_px": 1.0}
        if not ok:
            rec["reason"], rec["failed"] = "poor fit: silhouette IoU", ["iou"]
        recs.append(rec)
    recs[n // 2] = {"frame": n // 2, "timestamp_ns": 0, "model": MODEL.name, "ok": False, "reason": "lost"}
    return recs


def _arrays(recs):
    P = np.array([r.get("params", MODEL.zero()) for r in recs], float)
    J = np.array([[r["joints"][m] for m in MODEL.joint_names] if "joints" in r else np.zeros((16, 3)) for r in recs])
    return P, J


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("half", [1, 2, 3])
def test_streamed_equals_the_take_smoothed_at_once_and_keeps_verdicts(seed, half):
    recs = _take(seed)
    out = list(smoothed_records(iter(recs), MODEL, half=half, fps=FPS))
    assert [r["frame"] for r in out] == [r["frame"] for r in recs]
    for a, b in zip(recs, out):
        assert {k: v for k, v in b.items() if k not in ("params", "joints", "smoothed")} == \
            {k: v for k, v in a.items() if k not in ("params", "joints")}
    P, J = _arrays(recs)
    breaks = pose_breaks(recs, MODEL, fps=FPS)
    Q, JQ = smooth_poses(MODEL, P, J, half=half, breaks=breaks)
    h = segment_halves(breaks, half)
    for k, (a, b) in enumerate(zip(recs, out)):
        assert b.get("smoothed", False) == bool(h[k] > 0)
        if "params" in a:
            np.testing.assert_allclose(b["params"], Q[k], atol=1e-9)
            np.testing.assert_allclose([b["joints"][m] for m in MODEL.joint_names], JQ[k], atol=1e-9)
    assert "params" not in out[len(recs) // 2]
    assert MODEL.within_limits(np.array([r["params"] for r in out if "params" in r])).all()


def test_smoothing_brings_jittery_joints_nearer_their_clean_path():
    clean, noisy = _take(5, noise=0.0), _take(5, noise=0.03)
    out = list(smoothed_records(noisy, MODEL, half=2, fps=FPS))
    Jc, Jn = _arrays(clean)[1], _arrays(noisy)[1]
    Js = _arrays(out)[1]
    posed = np.array(["params" in r for r in noisy])
    assert np.linalg.norm(Js - Jc, axis=2)[posed].mean() < 0.8 * np.linalg.norm(Jn - Jc, axis=2)[posed].mean()


def test_breaks_a_jump_a_mirror_switch_and_a_gap_are_not_crossed():
    recs = _take(3, n=30)
    jump = 10  # the body moved a metre between frames 9 and 10: a recovery
    for r in recs[jump:]:
        if "params" in r:
            r["params"][0] += 1.0
            r["joints"] = {m: [x + 1.0, y, z] for m, (x, y, z) in r["joints"].items()}
    mirror = 20
    for r in recs[mirror:]:
        r["front_back_reported"] = "mirror"
    gap = 25
    for r in recs[gap:]:
        r["frame"] += 3
    b = pose_breaks(recs, MODEL, fps=FPS)
    assert b[[0, jump, mirror, gap, 15, 16]].all() and b.sum() == 6
    assert 1.0 * FPS > MAX_JOINT_SPEED_MPS
    whole = list(smoothed_records(recs, MODEL, half=3, fps=FPS))
    for lo, hi in ((0, jump), (jump, 15), (mirror, gap)):
        alone = list(smoothed_records(recs[lo:hi], MODEL, half=3, fps=FPS))
        assert alone == whole[lo:hi]


def test_the_look_ahead_is_the_window_half_and_an_interrupt_yields_every_record_read():
    recs = _take(4, n=20)
    read = []

    def source(stop_at=None):
        for r in recs:
            if r["frame"] == stop_at:
                raise KeyboardInterrupt
            read.append(r["frame"])
            yield r

    for r in smoothed_records(source(), MODEL, half=2, fps=FPS):
        assert read[-1] == min(r["frame"] + 2, len(recs) - 1)
    read.clear()
    out = []
    with pytest.raises(KeyboardInterrupt):
        for r in smoothed_records(source(stop_at=12), MODEL, half=2, fps=FPS):
            out.append(r)
    assert [r["frame"] for r in out] == list(range(12))
    assert out[11] == recs[11]  # the last read frame has no look-ahead: as fitted


def test_window_half_means_the_same_seconds_at_any_rate():
    assert [window_half(1 / 6, fps) for fps in (25.0, 30.0, 50.0, 60.0)] == [2, 2, 4, 5]
    assert window_half(0.0, 30.0) == 0 and window_half(1 / 30, 30.0) == 0
    with pytest.raises(ValueError):
        window_half(-1.0, 30.0)
