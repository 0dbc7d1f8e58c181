"""The walking-direction cue of the blob tracker (tracker.blobs.walk_heading), at seeded random poses."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.blobs.tracking import BlobOptions
from tracker.blobs.walk_heading import WalkHeading, walk_turn
from tracker.body.model import ROOT_TRANSLATION, load_model
from tracker.search.candidates import turn_about_vertical
from tracker.search.mirror import pelvis_heading


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40", height_m=1.75)


def _angle(v):
    return np.arctan2(v[1], v[0])


def test_walk_turn_weights_by_speed_and_wraps():
    rng = np.random.default_rng(3)
    for _ in range(50):
        f, d = rng.uniform(-np.pi, np.pi, 2)
        facing = np.array([np.cos(f), np.sin(f)]) * rng.uniform(0.1, 2.0)
        unit = np.array([np.cos(d), np.sin(d)])
        wrapped = np.angle(np.exp(1j * (d - f)))
        full = walk_turn(facing, 1.0 * unit, gain=0.5, speed_min=0.3, speed_full=0.6)
        assert full == pytest.approx(0.5 * wrapped, abs=1e-9)
        half = walk_turn(facing, 0.45 * unit, gain=0.5, speed_min=0.3, speed_full=0.6)
        assert half == pytest.approx(0.25 * wrapped, abs=1e-9)
        assert walk_turn(facing, 0.2 * unit, gain=0.5, speed_min=0.3, speed_full=0.6) == 0.0
    assert walk_turn(np.zeros(2), np.array([1.0, 0.0]), gain=0.5, speed_min=0.3, speed_full=0.6) == 0.0


def test_walk_turn_leaves_large_angles_alone():
    rng = np.random.default_rng(5)
    for _ in range(50):
        f, d = rng.uniform(-np.pi, np.pi, 2)
        wrapped = np.angle(np.exp(1j * (d - f)))
        got = walk_turn([np.cos(f), np.sin(f)], [np.cos(d), np.sin(d)], gain=1.0, speed_min=0.3, speed_full=0.6,
                        max_rad=np.radians(45.0))
        assert got == (pytest.approx(wrapped, abs=1e-9) if abs(wrapped) <= np.radians(45.0) else 0.0)


def test_walk_heading_turns_a_pose_toward_its_walk(model):
    rng = np.random.default_rng(7)
    t_idx = np.flatnonzero(model.param_kind == ROOT_TRANSLATION)
    for _ in range(10):
        p = turn_about_vertical(model, model.zero(), rng.uniform(-np.pi, np.pi), np.zeros(3))
        walk = rng.uniform(-np.pi, np.pi)
        wh = WalkHeading(model, gain=1.0, speed_min=0.3, speed_full=0.6, window_s=0.3)
        for k in range(12):  # 1 m/s along `walk`, 30 frames per second
            q = p.copy()
            q[t_idx[:2]] += (k / 30.0) * np.array([np.cos(walk), np.sin(walk)])
            wh.add(k / 30.0, q)
        assert np.allclose(wh.velocity(), [np.cos(walk), np.sin(walk)], atol=1e-9)
        turned = turn_about_vertical(model, q, wh.turn(q), q[t_idx])
        assert np.degrees(abs(np.angle(np.exp(1j * (_angle(pelvis_heading(model, turned)) - walk))))) < 0.01
        assert np.allclose(turned[t_idx], q[t_idx])
        wh.reset()
        assert wh.turn(q) == 0.0


def test_walk_options_validated(model):
    with pytest.raises(ValueError, match="gain"):
        WalkHeading(model, gain=1.5, speed_min=0.3, speed_full=0.6, window_s=0.3)
    with pytest.raises(ValueError, match="speed_min"):
        WalkHeading(model, gain=0.5, speed_min=0.6, speed_full=0.3, window_s=0.3)
    with pytest.raises(ValueError, match="window_s"):
        WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.0)
    with pytest.raises(ValueError, match="walk_source"):
        BlobOptions(walk_source="feet")


def test_walk_heading_from_points(model):
    rng = np.random.default_rng(11)
    v = rng.normal(size=2)
    wh = WalkHeading(model, gain=0.5, speed_min=0.3, speed_full=0.6, window_s=0.3)
    for k in range(20):
        wh.add(k / 25.0, point_xy=v * k / 25.0 + rng.normal(0, 1e-4, 2))
    assert np.allclose(wh.velocity(), v, atol=0.01)
