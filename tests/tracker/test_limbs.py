"""Limbs exchanged or lost (tracker.search.limbs and the Tracker's limb check)."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import JOINT_ROTATION, ROOT_ROTATION, load_model
from tracker.fitting.tracking import Tracker, TrackerOptions
from tracker.imaging.render import internal_edges, render_label_images
from tracker.search.limbs import (ARM_STARTS, ARMS, EXCHANGED, KEPT, LEGS, SAME, UNSURE, StrideWatch, ankle_crossing,
                                  ankle_separation, arm_candidates, exchange_limbs, exchange_verdict, leg_candidates, limb_dofs)
from tracker.synthetic.scene import ring_cameras
from tracker.body.kinematics import so3_exp
from tracker.search.mirror import mirror_map

MODEL = load_model("knossow40", height_m=1.75)
S = np.diag([1.0, -1.0, 1.0])


def _random_pose(rng) -> np.ndarray:
    p = MODEL.zero()
    p[:3] = rng.uniform(-0.5, 0.5, 3)
    p[MODEL.param_kind == ROOT_ROTATION] = rng.uniform(-1.0, 1.0, 3)
    j = MODEL.param_kind == JOINT_ROTATION
    p[j] = rng.uniform(MODEL.lower[j], MODEL.upper[j])
    return p


def _thorax_frame(params):
    """Every joint centre in the frame of the arms' parent (the pose with the root, spine and clavicle
    rotations undone: the arm DOF alone move the arms)."""
    q = np.asarray(params, dtype=float).copy()
    keep = set(limb_dofs(MODEL, ARMS)) - {k for k in limb_dofs(MODEL, ARMS) if "clavicle" in MODEL.param_names[k]}
    q[[k for k in range(MODEL.n_params) if k not in keep]] = 0.0
    return joint_centre_array(MODEL, forward(MODEL, q))


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
    assert set(cands) == {f"{side}_{s}" for side in ("left", "right") for s in ARM_STARTS}
    for name, q in cands.items():
        changed = set(np.flatnonzero(q != p))
        assert changed and changed <= arms, name
        assert all(MODEL.param_names[k].startswith(name.split("_")[0]) for k in changed), name


@pytest.mark.parametrize("seed", range(4))
def test_arm_starts_where_they_say(seed):
    """At seeded random poses, in the thorax's frame: a hanging arm's wrist well below its shoulder and
    beside the trunk; a bent one's elbow there too and its wrist before it (the pelvis heading), at
    elbow height; a raised one's wrist out sideways at shoulder height (the T-pose arm)."""
    rng = np.random.default_rng(seed)
    p = MODEL.clamp(_random_pose(rng))
    h = MODEL.height_m
    for side, out in (("left", 1.0), ("right", -1.0)):
        s, e, w = (MODEL.joint_names.index(f"{side}_{j}") for j in ("shoulder", "elbow", "wrist"))
        cands = dict(arm_candidates(MODEL, p))
        rel = {k: _thorax_frame(cands[f"{side}_{k}"]) for k in ("hanging", "bent", "raised")}
        hang, bent, up = rel["hanging"], rel["bent"], rel["raised"]
        assert hang[s, 2] - hang[w, 2] > 0.25 * h and abs(hang[w, 0] - hang[s, 0]) < 0.02 * h
        np.testing.assert_allclose(bent[e], hang[e], atol=1e-9)
        assert bent[w, 0] - bent[e, 0] > 0.1 * h and abs(bent[w, 2] - bent[e, 2]) < 0.02 * h
        assert out * (up[w, 1] - up[s, 1]) > 0.25 * h and abs(up[w, 2] - up[s, 2]) < 0.02 * h


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


def _wrist_error_m(record, truth, side) -> float:
    names = list(MODEL.joint_names)
    k = names.index(f"{side}_wrist")
    true = joint_centre_array(MODEL, forward(MODEL, truth))[k]
    return float(np.linalg.norm(np.array(record["joints"][names[k]]) - true))


def _arm_pose(p, side, abduction_deg, flexion_deg, elbow_deg) -> np.ndarray:
    q = p.copy()
    for dof, deg in (("upper_arm.abduction", abduction_deg), ("upper_arm.flexion", flexion_deg),
                     ("forearm.flexion", elbow_deg)):
        k = MODEL.param_index(f"{side}_{dof}")
        q[k] = np.radians(deg) * (1.0 if side == "left" else _mirror_sign(k))
    return MODEL.clamp(q)


def _mirror_sign(k: int) -> float:
    """The sign ``mirror_map`` gives the left-side DOF ``k`` on the right side."""
    index, sign = mirror_map(MODEL)
    return float(sign[index[k]])


def test_lost_arm_comes_back():
    """Ten seeded mid-stride poses with one arm held out sideways, the forearm up ("raised"), or hanging
    with the forearm forward before the belly ("bent"), each tracked for one frame from that arm wrong
    (for "raised" bent before the belly, inside the trunk's silhouette; for "bent" hanging straight).
    Without the limb check most wrists stay more than 15 cm off; with it at least four of those come back
    within 6 cm (the arm starts ``"bent"`` and ``"raised"`` of ``arm_candidates``: the "hanging" and
    "previous" starts alone bring none back), and the check never makes a wrist worse."""
    cams = ring_cameras(4, size=(320, 240))
    off = back = 0
    for seed in range(10):
        rng = np.random.default_rng(100 + seed)
        side = ("left", "right")[seed % 2]
        p = _stride(seed)
        if seed < 5:  # raised
            truth = _arm_pose(p, side, rng.uniform(-15, 5), rng.uniform(-10, 20), rng.uniform(40, 80))
            wrong = _arm_pose(p, side, -80, 10, 90)
        else:  # bent
            truth = _arm_pose(p, side, -80, rng.uniform(0, 20), rng.uniform(80, 110))
            wrong = _arm_pose(p, side, -80, 0, 0)
        frame = _render(truth, cams)
        errs = []
        for every in (0, 5):
            tr = Tracker(MODEL, cams, initial_params=wrong, recover=False, front_back=None,
                         options=TrackerOptions(limb_every=every))
            errs.append(_wrist_error_m(tr.step(0, 0, *frame), truth, side))
        assert errs[1] <= errs[0] + 0.01, (seed, errs)
        if errs[0] > 0.15:
            off += 1
            back += errs[1] < 0.06
    assert off >= 6 and back >= 4, (off, back)


@pytest.mark.parametrize("colour_due", [True, False])
def test_a_limb_lost_by_colour_makes_the_next_check_due(colour_due):
    """A frame tracked right needs no limb check; after a frame whose colour check found a limb lost the
    next frame is checked (``limb_colour_due``), once, and not without the option."""
    cams = ring_cameras(4, size=(320, 240))
    truth = _stride(0)
    frame = _render(truth, cams)
    tr = Tracker(MODEL, cams, initial_params=truth, recover=False, front_back=None,
                 options=TrackerOptions(limb_colour_due=colour_due))
    tr.step(0, 0, *frame)
    checks = tr.n_limb_checks
    tr.step(1, 33_333_333, *frame)
    assert tr.n_limb_checks == checks
    tr._colour_lost, tr._since_limbs = True, 10
    tr.step(2, 66_666_666, *frame)
    assert tr.n_limb_checks == checks + int(colour_due)
