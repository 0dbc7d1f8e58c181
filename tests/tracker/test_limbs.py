"""Limbs exchanged or lost (tracker.search.limbs and the Tracker's limb check)."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, load_model
from tracker.fitting.tracking import Tracker, TrackerOptions
from tracker.imaging.render import internal_edges, render_label_images
from tracker.search.limbs import (ARMS, EXCHANGED, KEPT, LEGS, SAME, UNSURE, StrideWatch, ankle_crossing,
                                  ankle_separation, arm_candidates, exchange_limbs, exchange_verdict, leg_candidates, limb_dofs)
from tracker.synthetic.scene import ring_cameras
from tracker.body.kinematics import so3_exp

MODEL = load_model("knossow40", height_m=1.75)
S = np.diag([1.0, -1.0, 1.0])


def _random_pose(rng) -> np.ndarray:
    p = MODEL.zero()
    p[:3] = rng.uniform(-0.5, 0.5, 3)
    p[MODEL.param_kind == ROOT_ROTATION] = rng.uniform(-1.0, 1.0, 3)
    j = MODEL.param_kind == JOINT_ROTATION
    p[j] = rng.uniform(MODEL.lower[j], MODEL.upper[j])
    return p


def _pelvis_frame(params, names):
    """The named joints in the pelvis frame (root rotation undone, pelvis origin at 0)."""
    pose = forward(MODEL, params)
    jc = joint_centre_array(MODEL, pose)
    R = so3_exp(params[MODEL.param_kind == ROOT_ROTATION])
    idx = [MODEL.joint_names.index(n) for n in names]
    return (jc[idx] - jc[MODEL.joint_names.index("pelvis")]) @ R


@pytest.mark.parametrize("chain, joints", [(LEGS, ("knee", "ankle")), (ARMS, ("elbow", "wrist"))])
def test_exchange_puts_each_limb_where_the_other_was_reflected(chain, joints):
    """At seeded random poses, in the pelvis frame each side's joints after the exchange are the other
    side's before, reflected in the sagittal plane (arms: with the trunk neither bent sideways nor
    twisted); everything else stays; twice is the identity."""
    rng = np.random.default_rng(12)
    left = [f"left_{j}" for j in joints]
    right = [f"right_{j}" for j in joints]
    others = [i for i in range(MODEL.n_params) if i not in set(limb_dofs(MODEL, chain))]
    for _ in range(10):
        p = _random_pose(rng)
        if chain == ARMS:  # the arms hang off the thorax: reflected in the pelvis frame when the trunk is
            p[[MODEL.param_index(n) for n in ("abdomen.bend", "abdomen.twist", "torso.bend", "torso.twist")]] = 0.0
        q = exchange_limbs(MODEL, p, chain)
        np.testing.assert_array_equal(q[others], p[others])
        np.testing.assert_allclose(exchange_limbs(MODEL, q, chain), p, atol=1e-12)
        np.testing.assert_allclose(_pelvis_frame(q, left), _pelvis_frame(p, right) @ S, atol=1e-9)
        np.testing.assert_allclose(_pelvis_frame(q, right), _pelvis_frame(p, left) @ S, atol=1e-9)
        assert not np.allclose(q, p)


def test_candidates_change_only_their_chain():
    rng = np.random.default_rng(5)
    p = MODEL.clamp(_random_pose(rng))
    prev = MODEL.clamp(_random_pose(rng))
    legs, arms = set(limb_dofs(MODEL, LEGS)), set(limb_dofs(MODEL, ARMS))
    for name, q in leg_candidates(MODEL, p):
        changed = set(np.flatnonzero(q != p))
        assert changed and changed <= legs, name
    cands = dict(arm_candidates(MODEL, p, prev))
    assert set(cands) == {"left_hanging", "right_hanging", "left_previous", "right_previous"}
    for name, q in cands.items():
        changed = set(np.flatnonzero(q != p))
        assert changed and changed <= arms, name
        assert all(MODEL.param_names[k].startswith(name.split("_")[0]) for k in changed), name
    names = list(MODEL.joint_names)
    for side in ("left", "right"):  # a hanging arm: the wrist well below the shoulder
        jc = joint_centre_array(MODEL, forward(MODEL, arm_candidates(MODEL, MODEL.zero())[0 if side == "left" else 1][1]))
        assert jc[names.index(f"{side}_shoulder"), 2] - jc[names.index(f"{side}_wrist"), 2] > 0.3 * MODEL.height_m


def test_stride_watch_fires_on_a_crossing_beyond_the_dead_band():
    w = StrideWatch(0.1)
    fired = [w.update(s) for s in (0.3, 0.05, -0.05, np.nan, -0.2, -0.3, 0.09, 0.15, 0.2)]
    assert fired == [False, False, False, False, True, False, False, True, False]
    w.reset()
    assert not w.update(-0.3)
    with pytest.raises(ValueError):
        StrideWatch(0.0)


def test_exchange_verdict():
    v = dict(margin=0.5, same_m=0.07)
    assert exchange_verdict(3.0, 2.0, 0.3, **v).choice == EXCHANGED
    assert exchange_verdict(3.0, 2.8, 0.3, **v).choice == UNSURE
    assert exchange_verdict(3.0, 3.2, 0.3, **v).choice == KEPT
    assert exchange_verdict(3.0, 1.0, 0.05, **v).choice == SAME
    assert exchange_verdict(3.0, np.nan, 0.3, **v).choice == KEPT


def _stride(seed: int) -> np.ndarray:
    """A mid-stride pose at a seeded place and heading: left leg forward, right back, knee bent."""
    rng = np.random.default_rng(seed)
    p = MODEL.zero()
    p[:2] = rng.uniform(-0.4, 0.4, 2)
    p[5] = rng.uniform(-np.pi, np.pi)
    ix = MODEL.param_index
    p[ix("left_thigh.flexion")], p[ix("right_thigh.flexion")] = np.radians(30.0), np.radians(-18.0)
    p[ix("right_shank.flexion")] = np.radians(35.0)
    p[ix("left_upper_arm.abduction")] = p[ix("right_upper_arm.abduction")] = np.radians(-65.0)
    return p


def _render(params, cameras):
    labels = render_label_images(MODEL, forward(MODEL, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    chamfer = {c.name: chamfer_images(sils[c.name], internal_edges(lab)) for c, lab in zip(cameras, labels)}
    return chamfer, sils


def _leg_error_m(record, truth) -> float:
    names = list(MODEL.joint_names)
    idx = [names.index(f"{s}_{j}") for s in ("left", "right") for j in ("knee", "ankle")]
    jc = joint_centre_array(MODEL, forward(MODEL, truth))[idx]
    return float(np.max(np.linalg.norm(np.array([record["joints"][names[i]] for i in idx]) - jc, axis=1)))


def _exchanged_track(truth, cams, frame, every: int):
    """Track ``frame`` from the truth, then carry the legs exchanged into the next fit of the same frame
    (as a fit that swapped them at the crossing would); returns (record, tracker)."""
    tr = Tracker(MODEL, cams, initial_params=truth, recover=False, front_back=None,
                 options=TrackerOptions(limb_every=every))
    first = tr.step(0, 0, *frame)
    assert first["ok"] and _leg_error_m(first, truth) < 0.03 and "limbs" not in first.get("failed", [])
    tr.params, tr.previous = exchange_limbs(MODEL, tr.params), None
    return tr.step(1, 33_333_333, *frame), tr


def test_legs_exchanged_after_a_crossing_are_corrected_and_never_a_false_ok():
    """Six seeded mid-stride poses tracked correctly for a frame, then with the legs exchanged: the
    stride watch sees the crossing and the check runs; without it the exchange stays on every seed
    (knees/ankles 0.8-1 m off), with it at least half are corrected (within 5 cm), and no frame is
    reported ok with a knee or ankle more than 8 cm off."""
    cams = ring_cameras(4, size=(320, 240))
    corrected = 0
    for seed in range(6):
        truth = _stride(seed)
        assert abs(ankle_separation(MODEL, truth)) > 0.2
        frame = _render(truth, cams)
        off, _ = _exchanged_track(truth, cams, frame, every=0)
        assert _leg_error_m(off, truth) > 0.3
        rec, tr = _exchanged_track(truth, cams, frame, every=5)
        assert tr.n_limb_checks == 1
        err = _leg_error_m(rec, truth)
        assert not (rec["ok"] and err > 0.08), (seed, err, rec.get("reason"))
        corrected += err < 0.05
    assert corrected >= 3


def test_limb_check_off():
    cams = ring_cameras(4, size=(320, 240))
    truth = _stride(0)
    tr = Tracker(MODEL, cams, initial_params=exchange_limbs(MODEL, truth), recover=False, front_back=None,
                 options=TrackerOptions(limb_every=0))
    tr.step(0, 0, *_render(truth, cams))
    assert tr.n_limb_checks == 0


def _crossed(params) -> np.ndarray:
    """``params`` with the legs exchanged and each thigh drawn 20° across the midline: each foot on the
    other side of the body (what a fit carried through a turn leaves)."""
    q = exchange_limbs(MODEL, params).copy()
    for side in ("left", "right"):
        q[MODEL.param_index(f"{side}_thigh.abduction")] = np.radians(-20.0)
    return MODEL.clamp(q)


def test_ankle_crossing_is_the_ankles_apart_across_the_hip_line():
    """Standing or striding (the thighs only flexed), the ankles are the thighs' pivots apart across the
    hip line (positive), crossed legs negative; the figure does not depend on where the body stands or
    which way it faces."""
    rng = np.random.default_rng(3)
    ankles = _pelvis_frame(MODEL.zero(), ["left_ankle", "right_ankle"])
    apart = float(ankles[0, 1] - ankles[1, 1])
    assert apart > 0.2 and ankle_crossing(MODEL, MODEL.zero()) == pytest.approx(apart, abs=1e-9)
    for seed in range(5):
        p = _stride(seed)
        assert ankle_crossing(MODEL, p) == pytest.approx(apart, abs=0.01)
        assert ankle_crossing(MODEL, _crossed(p)) < -0.05
        q = p.copy()
        q[:2] += rng.uniform(-1, 1, 2)
        q[5] += rng.uniform(-np.pi, np.pi)
        assert ankle_crossing(MODEL, q) == pytest.approx(ankle_crossing(MODEL, p), abs=1e-9)


def test_uncrossed_start_puts_each_foot_on_its_side_at_the_other_legs_place():
    for seed in range(5):
        crossed = _crossed(_stride(seed))
        cands = dict(leg_candidates(MODEL, crossed, crossed=True))
        assert "uncrossed" in cands and "uncrossed" not in dict(leg_candidates(MODEL, crossed))
        u = cands["uncrossed"]
        assert ankle_crossing(MODEL, u) > 0.1
        # fore-aft: the left ankle goes where the right one was along the heading, and back
        assert np.sign(ankle_separation(MODEL, u)) == -np.sign(ankle_separation(MODEL, crossed))
        assert set(np.flatnonzero(u != crossed)) <= set(limb_dofs(MODEL, LEGS))


@pytest.mark.parametrize("crossed_limit", [0.03, None])
def test_crossed_legs_are_uncrossed(crossed_limit):
    """Five seeded mid-stride poses tracked from the legs crossed (each foot reaching to the other's
    place): with ``limb_crossed`` the limb check runs on the first frame and at least three end within
    5 cm of the truth's knees and ankles, none reported ok further off than 8 cm; without it no check
    runs and every track keeps the legs crossed (more than 0.3 m off)."""
    cams = ring_cameras(4, size=(320, 240))
    corrected = 0
    for seed in range(5):
        truth = _stride(seed)
        tr = Tracker(MODEL, cams, initial_params=_crossed(truth), recover=False, front_back=None,
                     options=TrackerOptions(limb_crossed=crossed_limit))
        rec = tr.step(0, 0, *_render(truth, cams))
        err = _leg_error_m(rec, truth)
        assert not (rec["ok"] and err > 0.08), (seed, err, rec.get("reason"))
        if crossed_limit is None:
            assert tr.n_limb_checks == 0 and err > 0.3
        corrected += err < 0.05
    assert corrected >= 3 if crossed_limit is not None else corrected == 0
