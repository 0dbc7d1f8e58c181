"""Tracking loop on direct renders: convergence from perturbed poses, missing cameras, empty frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from segmentation.distance import chamfer_images
from tracker.synthetic.bvh import load_bvh
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import JOINT_ROTATION
from tracker.imaging.render import internal_edges, render_label_images
from tracker.synthetic.retarget import retarget_bvh
from tracker.synthetic.scene import ring_cameras
from tracker.fitting.tracking import Tracker, TrackerOptions

HOP = Path(__file__).resolve().parents[2] / "tracker" / "synthetic" / "data" / "scaled_131_03.bvh"


def render_chamfer(model, params, cameras) -> tuple[dict, dict]:
    """Chamfer images and silhouettes of the model at ``params`` seen by ``cameras`` (by name)."""
    labels = render_label_images(model, forward(model, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    chamfer = {c.name: chamfer_images(sils[c.name], internal_edges(lab)) for c, lab in zip(cameras, labels)}
    return chamfer, sils


def hop_scene() -> tuple:
    """The gate tests' scene: 4 ring cameras at 400×300 and the hop's pose at 0.5 s on ``knossow40``:
    ``(cameras, model, params, chamfer, silhouettes)``."""
    cameras = ring_cameras(4, size=(400, 300))
    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=0.5)
    model, p0 = rt.model, rt.params[0]
    return (cameras, model, p0, *render_chamfer(model, p0, cameras))


@pytest.fixture(scope="module")
def cameras():
    return ring_cameras(6, size=(800, 600))


@pytest.fixture(scope="module", params=["knossow40", "knossow54"])
def hop_pose(request):
    """A natural pose: frame 1.0 s of the bundled hop clip retargeted onto the model."""
    rt = retarget_bvh(load_bvh(HOP), model=request.param, frames=1, start_s=1.0)
    return rt.model, rt.params[0]


def perturb(model, p, rng, *, deg=10.0, root_m=0.05):
    q = p.copy()
    joints = model.param_kind == JOINT_ROTATION
    q[joints] += np.radians(rng.uniform(-deg, deg, joints.sum()))
    q[:3] += rng.uniform(-root_m, root_m, 3)
    return model.clamp(q)


#: converge fully (the tracking defaults stop earlier, for speed, on small inter-frame motion); a
#: tighter robust scale (renders have no outliers) and a stronger prior hold the weakly observed
#: DOF (hands, clavicles) near the start instead of letting them wander along flat directions
CONVERGE = TrackerOptions(max_iterations=40, reverse_min_px=2.0, f_scale=1.0, prior_rad=100.0, ftol=2e-3, rtol=0.0)


def test_perturbed_pose_converges_back(hop_pose, cameras, rng):
    """From the truth perturbed by up to 10° per joint and 5 cm at the root (joint centres start
    50–200 mm off), one frame converges back: < 1 px RMS, < 10 mm mean joint-centre error and
    < 2° mean joint error for both models.

    Joint error: the mean absolute error of the rotational DOF, every joint counted (wrists and
    hands included) except rotations of a part about its own long axis (twist, pronation: axis ±z
    in the part frame), which barely change a cone's outline and are weakly observable.
    Measured with ``CONVERGE`` over 12 seeds (12345–12356; this test runs 12345): knossow40 mean
    1.23° (0.82° here, worst 2.01°), knossow54 mean 1.44° (1.42° here, worst 1.96°).  Before the
    reverse term's on-silhouette test (``tracker.fitting.cost``) knossow54 was at 2.9° (4.6° here): the
    reverse residuals of the uncovered end caps pulled the hands and the head off the truth.
    """
    model, truth = hop_pose
    chamfer, _ = render_chamfer(model, truth, cameras)
    start = perturb(model, truth, rng)
    tracker = Tracker(model, cameras, initial_params=start, options=CONVERGE)
    rec = tracker.step(7, 123, chamfer)
    assert rec["ok"], rec.get("reason")
    joints = model.param_kind == JOINT_ROTATION
    err_deg = np.degrees(np.abs(np.asarray(rec["params"]) - truth))
    jc = joint_centre_array(model, forward(model, np.asarray(rec["params"])))
    jc_true = joint_centre_array(model, forward(model, truth))
    mpjpe_mm = 1e3 * np.linalg.norm(jc - jc_true, axis=1).mean()
    start_mm = 1e3 * np.linalg.norm(joint_centre_array(model, forward(model, start)) - jc_true, axis=1).mean()
    assert start_mm > 40.0  # the perturbation is not trivial
    assert rec["rms_px"] < 1.0
    assert mpjpe_mm < 10.0, (mpjpe_mm, start_mm)
    non_axial = joints & (np.abs(model.param_axis[:, 2]) < 0.5)
    assert {"left_hand", "right_hand"} <= {model.part_names[model.param_part[k]] for k in np.flatnonzero(non_axial)} \
        or model.name == "knossow40"  # knossow40's hands are rigid with the forearms
    assert err_deg[non_axial].mean() < 2.0, err_deg[non_axial].mean()
    assert rec["frame"] == 7 and rec["timestamp_ns"] == 123 and rec["cameras"] == 6
    assert rec["inside_fraction"] > 0.9 and rec["iterations"] >= 1 and rec["latency_ms"] >= 0
    assert set(rec["joints"]) >= {"pelvis", "head", "left_wrist", "right_ankle"}


def test_missing_camera_still_solves(cameras, rng):
    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=1.5)
    model, truth = rt.model, rt.params[0]
    chamfer, _ = render_chamfer(model, truth, cameras)
    del chamfer["cam2"]
    tracker = Tracker(model, cameras, initial_params=perturb(model, truth, rng, deg=4.0, root_m=0.02))
    rec = tracker.step(0, 0, chamfer)
    assert rec["ok"], rec.get("reason")
    assert rec["cameras"] == 5
    jc = joint_centre_array(model, forward(model, np.asarray(rec["params"])))
    assert 1e3 * np.linalg.norm(jc - joint_centre_array(model, forward(model, truth)), axis=1).mean() < 15.0


def test_empty_and_bad_frames_are_records_not_exceptions(cameras):
    from tracker.body.model import load_model

    model = load_model("knossow40")
    empty = np.zeros((600, 800), np.uint8)
    chamfer = {c.name: chamfer_images(empty, empty) for c in cameras}
    tracker = Tracker(model, cameras, initial_params=model.zero())
    rec = tracker.step(3, 99, chamfer)
    assert rec["ok"] is False and "silhouette" in rec["reason"] and rec["cameras"] == 0
    rec = tracker.step(4, 100, {})
    assert rec["ok"] is False and rec["frame"] == 4
    rec = tracker.step(5, 101, {"nonexistent": chamfer["cam0"]})
    assert rec["ok"] is False and "nonexistent" in rec["reason"]
    # silhouettes given and all empty: same answer
    rec = tracker.step(6, 102, chamfer, silhouettes={c.name: empty for c in cameras})
    assert rec["ok"] is False


def test_constant_velocity_prediction_and_bad_arguments(cameras):
    from tracker.body.model import load_model

    model = load_model("knossow40")
    tr = Tracker(model, cameras, initial_params=model.zero(), options=TrackerOptions(constant_velocity=True))
    tr.previous, tr.params = model.zero(), model.zero() + 0.01
    np.testing.assert_allclose(tr.predict(), model.clamp(model.zero() + 0.02))
    # damped, across a frame gap twice the last one: p + d * 2 * (p - p_prev)
    rng = np.random.default_rng(3)
    prev = model.random_params(rng, fraction=0.3)
    last = model.clamp(prev + rng.normal(0, 0.01, prev.size))
    tr = Tracker(model, cameras, initial_params=model.zero(), options=TrackerOptions(velocity_damping=0.5))
    tr.previous, tr.params, tr._frames = prev, last, (10, 11)
    np.testing.assert_allclose(tr.predict(13), model.clamp(last + 0.5 * 2.0 * (last - prev)))
    np.testing.assert_allclose(tr.predict(12), model.clamp(last + 0.5 * (last - prev)))
    with pytest.raises(ValueError, match="solver"):
        Tracker(model, cameras, solver="newton")
    with pytest.raises(ValueError, match="initial_params"):
        Tracker(model, cameras, initial_params=np.zeros(3))


def test_an_overshooting_prediction_is_fitted_from_the_last_pose_too(cameras):
    """The body stops dead while the constant-velocity prediction carries on by a large last step
    (up to 25° per joint, 15 cm at the root): with ``restart_step`` the frame is fitted from the
    last pose too and the fit of lower cost is kept (here the one from the last pose, on the truth);
    a small step is not fitted twice."""
    from tracker.fitting.tracking import fit_frame

    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=1.0)
    model, truth = rt.model, rt.params[0]
    chamfer, sils = render_chamfer(model, truth, cameras)
    jc_true = joint_centre_array(model, forward(model, truth))

    def run(previous, step):
        tr = Tracker(model, cameras, initial_params=truth, options=TrackerOptions(restart_step=step))
        tr.previous, tr._frames = previous, (0, 1)
        start = tr.predict(2)
        rec = tr.step(2, 2, chamfer, silhouettes=sils)
        mm = 1e3 * np.linalg.norm(joint_centre_array(model, forward(model, np.asarray(rec["params"]))) - jc_true,
                                  axis=1).mean()
        return tr, rec, mm, start

    previous = perturb(model, truth, np.random.default_rng(5), deg=25.0, root_m=0.15)
    off, rec_off, mm_off, start = run(previous, None)
    on, rec_on, mm_on, _ = run(previous, 0.1)
    assert off.n_restarts == 0 and (on.n_restarts, on.n_restarts_taken) == (1, 1)
    # the kept fit is the cheaper of the two starts' fits, each as fit_frame gives it
    costs = [fit_frame(model, cameras, chamfer, s, prediction=truth, options=on.options)[0].cost
             for s in (start, truth)]
    assert on.last_result.cost == pytest.approx(min(costs)) and costs[1] < costs[0]
    assert off.last_result.cost == pytest.approx(costs[0])
    assert rec_on["ok"] and mm_on < 5.0 and mm_off > 2 * mm_on, (mm_on, mm_off)
    small, rec_small, mm_small, _ = run(perturb(model, truth, np.random.default_rng(6), deg=1.0, root_m=0.005), 0.1)
    assert small.n_restarts == 0 and rec_small["ok"] and mm_small < 5.0


def test_lost_track_recovers_from_the_silhouettes(cameras):
    """A jump the local fit cannot follow (the subject turned 90° and stepped 0.8 m between two
    frames): bad frames are reported ``ok: false`` and, after ``patience`` of them, the pose is
    searched again from the silhouettes (seeded by the last good pose) and tracking resumes."""
    from tracker.search.candidates import turn_about_vertical

    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=0.5)
    model, p0 = rt.model, rt.params[0]
    p1 = turn_about_vertical(model, p0, np.pi / 2, joint_centre_array(model, forward(model, p0))[0])
    p1[:2] += [0.6, -0.5]
    ch0, sil0 = render_chamfer(model, p0, cameras)
    ch1, sil1 = render_chamfer(model, p1, cameras)
    tracker = Tracker(model, cameras, initial_params=p0, patience=2)
    assert tracker.step(0, 0, ch0, sil0)["ok"]
    recs = [tracker.step(k, k, ch1, sil1) for k in (1, 2, 3, 4, 5)]
    assert not recs[0]["ok"] and recs[0]["reason"].startswith("poor fit")
    assert tracker.n_initialisations >= 1
    # after a search the front/back guard (tracker.fitting.hypotheses) weighs the pose against its
    # mirror again: a frame or two may be "front/back ambiguous", never a poor fit
    assert all(r["ok"] or r["reason"].startswith("front/back ambiguous") for r in recs[2:])
    assert recs[-1]["ok"], [r.get("reason") for r in recs]
    jc = joint_centre_array(model, forward(model, np.asarray(recs[-1]["params"])))
    assert 1e3 * np.linalg.norm(jc - joint_centre_array(model, forward(model, p1)), axis=1).mean() < 30.0


def test_rms_limit_follows_the_running_median_and_iou_is_checked_sparingly(cameras):
    """The RMS limit is ``rms_ratio`` × the median RMS of the recent good frames (floored at
    ``max_rms_px``, capped at ``max_rms_ceiling_px``); the silhouette IoU is rendered on the first
    frame and then every ``iou_every`` frames while the cheap figures are fine (every frame with
    ``iou_every=1``)."""
    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=1.0)
    model, truth = rt.model, rt.params[0]
    chamfer, sils = render_chamfer(model, truth, cameras)
    opts = TrackerOptions(max_rms_px=1.0, rms_ratio=2.5, iou_every=3)  # renders fit to ~0.5 px
    tracker = Tracker(model, cameras, initial_params=truth, options=opts)
    assert tracker.rms_limit() == pytest.approx(1.0)  # no good frame yet: the floor
    recs = [tracker.step(k, k, chamfer, sils) for k in range(4)]
    assert all(r["ok"] for r in recs), [r.get("reason") for r in recs]
    assert 2.5 * np.median([r["rms_px"] for r in recs]) > 1.0
    assert tracker.rms_limit() == pytest.approx(2.5 * np.median([r["rms_px"] for r in recs]))
    assert ["iou" in r for r in recs] == [True, False, False, True]
    assert min(r["iou"] for r in recs if "iou" in r) > 0.85
    capped = Tracker(model, cameras, initial_params=truth,
                     options=TrackerOptions(max_rms_px=1.0, rms_ratio=1e3, max_rms_ceiling_px=1.1, iou_every=1))
    recs = [capped.step(k, k, chamfer, sils) for k in range(2)]
    assert all("iou" in r for r in recs)
    assert capped.rms_limit() == pytest.approx(1.1)


def test_a_track_started_mirrored_is_turned_round(cameras):
    """A track started on the mirror of the truth (turned 180°, left and right swapped) fits the
    silhouettes nearly as well as the truth on some frames (measured: RMS 1.9 px, IoU 0.86 on the
    first) and stays turned round frame after frame (joint centres ~200 mm off) unless the periodic
    front/back check turns it (recovery off here, to see the check alone): with
    ``front_back_every=4`` it is turned at the 4th frame and runs on the truth after.  (Frames 1–2
    are flagged poor fits; recovery, on in the tracker's defaults, would search again there.)"""
    from tracker.search.mirror import mirror_params

    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=8, start_s=0.5, fps=30)
    model = rt.model
    renders = [render_chamfer(model, p, cameras) for p in rt.params]

    def run(every):
        opts = TrackerOptions(front_back_every=every)
        tracker = Tracker(model, cameras, initial_params=mirror_params(model, rt.params[0]), options=opts,
                          recover=False, front_back=None)  # the periodic check alone, not the guard
        errs, oks = [], []
        for k, (ch, sil) in enumerate(renders):
            rec = tracker.step(k, k, ch, sil)
            jc = joint_centre_array(model, forward(model, np.asarray(rec["params"])))
            errs.append(1e3 * np.linalg.norm(jc - joint_centre_array(model, forward(model, rt.params[k])), axis=1).mean())
            oks.append(rec["ok"])
        return tracker, errs, oks

    off, errs_off, _ = run(0)
    assert off.n_front_back_checks == 0 and min(errs_off) > 100.0, errs_off  # stays turned round
    on, errs_on, oks = run(4)
    assert on.n_front_back_checks == 2 and on.n_turned == 1, (on.n_front_back_checks, on.n_turned)
    assert min(errs_on[:3]) > 100.0 and max(errs_on[3:]) < 25.0, errs_on  # measured 17-18 mm
    assert all(oks[3:]), oks


def test_the_second_start_takes_a_limb_from_the_other_fit(cameras):
    """Two fits each with one limb wrong (the right arm folded in front of the torso in one, the left
    leg off in the other): the kept fit's wrong limb is exchanged for the other fit's, refitted, and
    the result is cheaper and on the truth (``TrackerOptions.restart_exchange``)."""
    from tracker.fitting.tracking import fit_frame

    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=1.0)
    model, truth = rt.model, rt.params[0]
    chamfer, sils = render_chamfer(model, truth, cameras)
    jc_true = joint_centre_array(model, forward(model, truth))
    arm_off, leg_off = truth.copy(), truth.copy()
    arm_off[model.param_index("right_upper_arm.flexion")] += 1.2
    arm_off[model.param_index("right_forearm.flexion")] += 1.5
    leg_off[model.param_index("left_thigh.flexion")] += 0.9
    arm_off, leg_off = model.clamp(arm_off), model.clamp(leg_off)
    short = TrackerOptions(max_iterations=2, restart_step=0.1)

    def errors(params):
        return np.linalg.norm(joint_centre_array(model, forward(model, np.asarray(params))) - jc_true, axis=1)

    wrist, ankle = model.joint_names.index("right_wrist"), model.joint_names.index("left_ankle")
    tr = Tracker(model, cameras, initial_params=truth, options=TrackerOptions(restart_step=0.1))
    kept_res, cost = fit_frame(model, cameras, chamfer, arm_off, prediction=truth, options=short)
    other_res, _ = fit_frame(model, cameras, chamfer, leg_off, prediction=truth, options=short)
    assert errors(kept_res.params)[wrist] > 0.15 and errors(other_res.params)[ankle] > 0.15
    terms = cost.evaluate(np.asarray(kept_res.params))
    got = tr._exchange_limb(cameras, chamfer, (kept_res, terms, terms.rms_px(), terms.inside_fraction()), other_res)
    assert tr.n_restart_exchanges == 1 and got[0].cost < kept_res.cost
    e = errors(got[0].params)
    assert e[wrist] < 0.03 and e[ankle] < 0.03, (e[wrist], e[ankle])
    # a limb both fits agree on is not tried: the kept fit with itself as the other is returned as it is
    same = tr._exchange_limb(cameras, chamfer, got, got[0])
    assert same is got and tr.n_restart_exchanges == 1
