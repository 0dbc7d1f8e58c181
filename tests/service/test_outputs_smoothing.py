"""1€ smoothing for consumers: jitter (frame-to-frame acceleration of the error to the truth) reduced on
the noisy take, no larger error; lag under one frame on a 10 cm step; reset across not-ok gaps; the
records keep their raw poses; rotation vectors stay continuous through ±π."""

from __future__ import annotations

import numpy as np
import pytest

from service.outputs.smoothing import smooth_records
from service.wire.records import PoseRecord
from tracker.body.filters import DEFAULT_BETA, DEFAULT_MIN_CUTOFF_HZ, OneEuroFilter, parse_one_euro, unwrap_rotation_vector

FPS = 30.0


def _jitter_and_error(records, truth):
    """RMS second difference of (joints - truth) over runs of ok frames, and RMS error, metres."""
    frames, names = truth["frames"], truth["names"]
    err = {r.frame: np.array([r.get("joints")[n] for n in names]) - truth["joints"][r.frame - frames[0]]
           for r in records if r.ok}
    acc = [err[f + 1] - 2 * err[f] + err[f - 1] for f in err if f - 1 in err and f + 1 in err]
    return float(np.sqrt(np.mean(np.square(acc)))), float(np.sqrt(np.mean([np.square(e) for e in err.values()])))


def test_jitter_reduced_on_the_noisy_take():
    pytest.importorskip("tracker.synthetic.retarget")
    from tests.support.outputs import make_take

    records, truth = make_take()
    raw = [r.to_bytes() for r in records]
    smooth = smooth_records(records, DEFAULT_MIN_CUTOFF_HZ, DEFAULT_BETA, FPS)
    assert [r.to_bytes() for r in records] == raw  # the records keep the raw pose
    j0, e0 = _jitter_and_error(records, truth)
    j1, e1 = _jitter_and_error(smooth, truth)
    assert j1 < 0.5 * j0  # measured: 35 -> 13 mm per frame^2
    assert e1 <= e0       # and no larger error to the truth (15.2 -> 13.6 mm)


def _crossing(y: np.ndarray, level: float) -> float:
    """First fractional index where y reaches ``level`` (linear interpolation between samples)."""
    k = int(np.argmax(y >= level))
    return k - 1 + (level - y[k - 1]) / (y[k] - y[k - 1])


@pytest.mark.parametrize("step_m", [0.1, 0.3])
def test_step_lag_under_one_frame(step_m):
    """The input and the output cross half the step; the output at most one frame later."""
    x = np.r_[np.zeros(30), np.full(30, step_m)]
    recs = [PoseRecord.from_dict({"frame": k, "timestamp_ns": int(k * 1e9 / FPS), "ok": True,
                                  "joints": {"pelvis": [float(v), 0.0, 1.0]}}) for k, v in enumerate(x)]
    y = np.array([r.get("joints")["pelvis"][0] for r in smooth_records(recs, DEFAULT_MIN_CUTOFF_HZ, DEFAULT_BETA, FPS)])
    lag = _crossing(y, step_m / 2) - _crossing(x, step_m / 2)
    assert 0 <= lag < 1.0
    assert abs(y[-1] - step_m) < 0.01 * step_m  # settles


def test_not_ok_resets_and_first_sample_passes():
    recs = [PoseRecord.from_dict({"frame": k, "timestamp_ns": k, "ok": True, "params": [float(k)] * 6,
                                  "joints": {"head": [float(k), 0.0, 0.0]}}) for k in range(5)]
    recs.insert(3, PoseRecord.from_dict({"frame": 3, "timestamp_ns": 3, "ok": False, "reason": "lost"}))
    recs = [r if i < 3 else PoseRecord.from_dict({**r.fields, "frame": r.frame + 1}) for i, r in enumerate(recs)]
    out = smooth_records(recs, 1.0, 0.0, FPS)
    assert out[0].get("joints") == recs[0].get("joints")
    assert out[1].get("joints")["head"][0] < 1.0            # smoothed
    assert not out[3].ok and out[3] is recs[3]
    assert out[4].get("joints") == recs[4].get("joints")    # first after the gap passes unchanged
    assert out[4].get("params") == recs[4].get("params")


def test_filter_rules_and_spec():
    f = OneEuroFilter(1.0, 0.0)
    assert f(np.array([1.0, 2.0]), 1 / FPS).tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match="dt"):
        f(np.array([1.0, 2.0]), 0.0)
    assert parse_one_euro("one-euro") == (DEFAULT_MIN_CUTOFF_HZ, DEFAULT_BETA)
    assert parse_one_euro("one-euro:0.5,3") == (0.5, 3.0) and parse_one_euro("off") is None
    for bad in ("median", "one-euro:1", "one-euro:-1,2"):
        with pytest.raises(ValueError):
            parse_one_euro(bad)


def test_rotation_vector_unwrap_is_the_same_rotation_and_continuous(rng):
    from scipy.spatial.transform import Rotation

    axis = np.array([0.0, 0.0, 1.0])
    prev = (np.pi - 0.05) * axis
    r = -(np.pi - 0.03) * axis  # the principal vector just past pi: flipped
    u = unwrap_rotation_vector(r, prev)
    assert np.linalg.norm(u - prev) < 0.1
    for _ in range(20):
        r, ref = rng.normal(size=3) * 2, rng.normal(size=3) * 3
        u = unwrap_rotation_vector(r, ref)
        np.testing.assert_allclose(Rotation.from_rotvec(u).as_matrix(), Rotation.from_rotvec(r).as_matrix(), atol=1e-9)
        assert np.linalg.norm(u - ref) <= np.linalg.norm(r - ref) + 1e-12
