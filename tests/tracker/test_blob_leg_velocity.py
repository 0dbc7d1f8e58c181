"""The legs' velocity carried into the blob tracker's start (tracker.blobs.leg_velocity), at seeded poses."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.blobs.leg_velocity import LegVelocity, leg_params, thigh_flexions
from tracker.blobs.tracking import BlobOptions, BlobTracker
from tracker.body.model import JOINT_ROTATION, load_model


@pytest.fixture(scope="module")
def model():
    return load_model("knossow40", height_m=1.75)


def _pose(model, rng, scale=0.3):
    return model.clamp(scale * rng.standard_normal(model.n_params)
                       * (model.param_kind == JOINT_ROTATION))


def test_leg_params_are_the_legs_rotations(model):
    legs = leg_params(model)
    names = [model.part_names[p] for p in model.param_part[legs]]
    assert legs.any() and all(n.split("_", 1)[1] in ("thigh", "shank", "foot") for n in names)
    assert {n.split("_", 1)[0] for n in names} == {"left", "right"}
    assert np.all(model.param_kind[legs] == JOINT_ROTATION)
    leg_parts = {"left_thigh", "left_shank", "left_foot", "right_thigh", "right_shank", "right_foot"}
    missed = [i for i in np.flatnonzero(~legs)
              if model.param_kind[i] == JOINT_ROTATION and model.part_names[model.param_part[i]] in leg_parts]
    assert not missed


def test_rate_is_the_mean_change_of_the_legs_only(model):
    rng = np.random.default_rng(11)
    legs = leg_params(model)
    for frames in (2, 3, 5):
        lv = LegVelocity(model, gain=1.0, frames=frames, flexion_only=False, antiphase=False)
        base = _pose(model, rng, 0.2)
        step = 0.02 * rng.standard_normal(model.n_params)
        for k in range(frames + 2):  # more poses than the history holds: the rate is over the last ``frames``
            lv.add(base + k * step)
        rate = lv.rate()
        assert np.allclose(rate[legs], step[legs], atol=1e-12)
        assert np.all(rate[~legs] == 0.0)
        start = base + 0.1 * rng.standard_normal(model.n_params) * (model.param_kind == JOINT_ROTATION)
        want = model.clamp(start + rate)
        assert np.allclose(lv.start(start), want)
        assert np.allclose(lv.start(start)[~legs], model.clamp(start)[~legs])


def test_no_rate_without_history_and_after_reset(model):
    rng = np.random.default_rng(12)
    lv = LegVelocity(model, gain=1.0, frames=3, flexion_only=False, antiphase=False)
    p = _pose(model, rng)
    assert np.all(lv.rate() == 0.0)
    lv.add(p)
    assert np.all(lv.rate() == 0.0)
    lv.add(_pose(model, rng))
    assert np.any(lv.rate() != 0.0)
    lv.reset()
    assert np.all(lv.rate() == 0.0)
    assert np.allclose(lv.start(p), model.clamp(p))


def test_start_stays_within_the_joint_limits(model):
    rng = np.random.default_rng(13)
    lv = LegVelocity(model, gain=1.0, frames=2, flexion_only=False, antiphase=False)
    p = _pose(model, rng)
    lv.add(p)
    lv.add(p + 5.0 * leg_params(model))  # a huge rate: the start is clamped
    out = lv.start(p)
    assert np.allclose(out, model.clamp(out))


def test_options_validation_and_default_on(model):
    with pytest.raises(ValueError):
        LegVelocity(model, gain=-0.1)
    with pytest.raises(ValueError):
        LegVelocity(model, frames=1)
    o = BlobOptions()
    assert o.leg_velocity_gain == 1.0 and o.leg_velocity_flexion_only and o.leg_velocity_antiphase


def test_speed_weight_gates_the_start(model):
    from tracker.blobs.walk_heading import speed_weight

    rng = np.random.default_rng(14)
    lv = LegVelocity(model, gain=1.0, frames=2, flexion_only=False, antiphase=False)
    p = _pose(model, rng, 0.1)
    lv.add(p)
    lv.add(p + 0.01 * leg_params(model))
    for speed, w in ((0.1, 0.0), (0.3, 0.0), (0.45, 0.5), (0.6, 1.0), (1.5, 1.0)):
        u = rng.standard_normal(2)
        got = speed_weight(speed * u / np.linalg.norm(u), speed_min=0.3, speed_full=0.6)
        assert got == pytest.approx(w, abs=1e-12)
        assert np.allclose(lv.start(p, got), model.clamp(p + w * 0.01 * leg_params(model)))


def _flexions(model):
    return np.array([n.endswith(".flexion") for n in model.param_names]) & leg_params(model)


def test_only_the_flexions_carried_while_the_thighs_swing_apart(model):
    """Default restrictions: a stride (thighs' flexion rates of opposite signs) carries the legs'
    flexions only; the same step with both thighs moving one way carries nothing."""
    rng = np.random.default_rng(15)
    flex = _flexions(model)
    left, right = thigh_flexions(model)
    for _ in range(5):
        lv = LegVelocity(model, gain=1.0, frames=3)
        base = _pose(model, rng, 0.2)
        step = 0.03 * rng.standard_normal(model.n_params)
        step[left], step[right] = abs(step[left]) + 0.01, -abs(step[right]) - 0.01  # a stride
        for k in range(3):
            lv.add(base + k * step)
        rate = lv.rate()
        assert np.allclose(rate[flex], step[flex], atol=1e-12)
        assert np.all(rate[~flex] == 0.0)
        lv.reset()
        step[right] = -step[right]  # both thighs the same way: no stride
        for k in range(3):
            lv.add(base + k * step)
        assert np.all(lv.rate() == 0.0)
        assert np.allclose(lv.start(base), model.clamp(base))


def test_blob_options_reach_the_tracker(model):
    """``BlobOptions``' restrictions are the tracker's: off, a same-way step of every leg parameter is carried."""
    from tests.tracker.test_blobs import _cube_scene, _ring

    cams = _ring(2)
    bgs, _ = _cube_scene(np.random.default_rng(0), cams, (0, 0, 0))
    assert BlobOptions().leg_velocity_flexion_only and BlobOptions().leg_velocity_antiphase
    for restricted in (True, False):
        o = BlobOptions(leg_velocity_gain=1.0, leg_velocity_flexion_only=restricted, leg_velocity_antiphase=restricted)
        lv = BlobTracker(model, cams, {c.name: m for c, m in zip(cams, bgs)}, options=o)._legs
        lv.add(model.zero())
        lv.add(model.zero() + 0.01 * leg_params(model))
        assert np.any(lv.rate() != 0.0) != restricted
