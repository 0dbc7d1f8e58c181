"""Loss detection and recovery: a wrong warm start is flagged lost and re-initialised from the hull."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.fitting.cost import ChamferCost
from tracker.search.initialise import SearchOptions, initialise
from tracker.search.scoring import chamfer_from_silhouette, rendered_views
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.search.candidates import limb_chains, turn_about_vertical
from tracker.search.recovery import LossMonitor, LossState, recover
from tracker.imaging.render import render_silhouettes
from tracker.synthetic.scene import ring_cameras
from tracker.fitting.tracking import TrackerOptions, fit_frame


def test_monitor_counts_consecutive_bad_frames():
    mon = LossMonitor(max_rms_px=5.0, min_inside_fraction=0.7, patience=3)
    good = {"ok": True, "rms_px": 1.2, "inside_fraction": 0.95}
    bad_rms = {"ok": True, "rms_px": 9.0, "inside_fraction": 0.95}
    bad_inside = {"ok": True, "rms_px": 1.0, "inside_fraction": 0.4}
    assert mon.update(good) == LossState("ok", 0)
    s1 = mon.update(bad_rms)
    assert s1.state == "suspect" and s1.bad_frames == 1 and "rms" in s1.reason
    s2 = mon.update(bad_inside)
    assert s2.state == "suspect" and "inside" in s2.reason
    s3 = mon.update({"ok": False, "reason": "no camera with a non-empty silhouette"})
    assert s3.lost and s3.bad_frames == 3 and "no camera" in s3.reason
    assert mon.update(bad_rms).lost
    assert not mon.update(good).lost and mon.bad_frames == 0
    # NaN quality (no contour point used) is bad, not silently good
    assert mon.update({"rms_px": float("nan"), "inside_fraction": float("nan")}).state == "suspect"
    with pytest.raises(ValueError, match="patience"):
        LossMonitor(patience=0)
    with pytest.raises(ValueError, match="min_inside_fraction"):
        LossMonitor(min_inside_fraction=1.5)


def test_turn_about_vertical_is_a_rigid_turn(rng):
    model = load_model("knossow40")
    p = model.random_params(rng, fraction=0.5)
    pivot = np.array([0.3, -0.2, 0.0])
    q = turn_about_vertical(model, p, 0.7, pivot)
    a, b = joint_centre_array(model, forward(model, p)), joint_centre_array(model, forward(model, q))
    c, s = np.cos(0.7), np.sin(0.7)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    assert np.allclose(b, (a - pivot) @ Rz.T + pivot, atol=1e-9)
    chains = limb_chains(model)
    allj = np.concatenate(list(chains.values()))
    assert len(allj) == len(set(allj)) == int((model.param_kind == 2).sum())


def test_wrong_warm_start_is_flagged_lost_and_recovered():
    model = load_model("knossow40")
    cams = ring_cameras(6)
    rng = np.random.default_rng(21)
    last_good = model.random_params(rng, fraction=0.3)
    last_good[:2] = [-0.2, 0.1]
    # since the last good frame the subject turned 90° and walked 40 cm, and moved the limbs a little
    truth = turn_about_vertical(model, last_good, np.pi / 2, forward(model, last_good).translation[0])
    truth[:2] += [0.4, 0.0]
    joints = model.param_kind == 2
    truth[joints] += rng.normal(0.0, np.radians(4.0), joints.sum())
    truth = model.clamp(truth)
    sils = render_silhouettes(model, forward(model, truth), cams)
    views = {c.name: s for c, s in zip(cams, sils)}
    chamfer = [chamfer_from_silhouette(s) for s in sils]
    cost = ChamferCost(model, cams, chamfer)
    mon = LossMonitor(max_rms_px=6.0, min_inside_fraction=0.6, patience=3)
    assert mon.update(cost.evaluate(truth)).state == "ok"
    # the tracker's own fit from the warm start ends far off and is flagged, three frames running
    fit, _ = fit_frame(model, cams, dict(zip(views, chamfer)), last_good)
    terms = cost.evaluate(fit.params)
    truth_joints = joint_centre_array(model, forward(model, truth))
    warm_err = np.linalg.norm(joint_centre_array(model, terms.pose) - truth_joints, axis=1)
    assert warm_err.mean() > 0.1
    states = [mon.update(terms) for _ in range(3)]
    assert [s.state for s in states] == ["suspect", "suspect", "lost"]
    res = recover(model, cams, views, None, last_good, options=TrackerOptions().recover_search)  # the Tracker's call
    err = np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                         - joint_centre_array(model, forward(model, truth)), axis=1)
    assert err.mean() < 0.030, dict(zip(model.joint_names, np.round(1e3 * err)))
    assert mon.update(cost.evaluate(res.params)).state == "ok"
    search, facing = res.label.rsplit("/", 1)  # the search's winner, then the front/back check
    assert res.score > 0.85 and search in ("local", "last", "hint", "T", "A") and facing in ("kept", "mirrored")


def test_recover_rejects_bad_last_pose():
    model = load_model("knossow40")
    cams = ring_cameras(2)
    views = {c.name: np.zeros((c.height, c.width), np.uint8) for c in cams}
    with pytest.raises(ValueError, match="last_good_params"):
        recover(model, cams, views, None, np.zeros(3))


def test_real_dancer_initialise_then_recover(shared_data):
    """A real 8-view frame (a dancer in a dress, arms out: neither T nor A): the reference-pose
    search with a limb search on the pose and its front/back mirror places the body and the
    limbs (IoU 0.65; 0.55 without the limb search and mirror), the any-pose search from there
    does not lose it."""
    import cv2

    from capture.calib_formats import read_projection_matrix
    from tracker.search.hull import visual_hull
    from tracker.search.candidates import estimate_height

    folder = shared_data / "dancer_8view"
    masks = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted(folder.glob("silh_cam*.pbm"))]
    cams = [read_projection_matrix(folder / "calibration" / f"cam{i:02d}.xml", size=(780, 582)) for i in range(8)]
    views = {c.name: m for c, m in zip(cams, masks)}
    hull = visual_hull(cams, masks, min_voxel_m=0.03)
    model = load_model("knossow40", height_m=estimate_height(hull, load_model("knossow40")))
    assert 1.60 < model.height_m < 1.70
    first = initialise(model, cams, views)
    again = recover(model, cams, views, None, first.params)
    assert first.score > 0.6 and again.score > max(first.score - 0.01, 0.6)
    pose = forward(model, again.params)
    trunk = [model.joint_names.index(n) for n in ("pelvis", "spine", "neck")]
    assert hull.contains(joint_centre_array(model, pose)[trunk]).all()


def test_recover_from_a_mirrored_last_pose_faces_the_right_way():
    """The last good pose faces backwards (the front/back mirror of the truth, as a track that
    followed the wrong facing): recovery's final front/back check turns it round."""
    from tracker.synthetic.bvh import load_bvh
    from tracker.search.mirror import mirror_params
    from tracker.synthetic.retarget import retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    mot = retarget_bvh(load_bvh(bundled_motion("scaled_131_03")), frames=1, start_s=0.0)  # a leaning crouch
    model, truth = mot.model, mot.params[0]
    cams = ring_cameras(4, size=(320, 240), start_deg=20.0)
    sils = render_silhouettes(model, forward(model, truth), cams)
    views = {c.name: s for c, s in zip(cams, sils)}
    res = recover(model, cams, views, None, mirror_params(model, truth))
    heading = [forward(model, p).rotation[0][:2, 0] for p in (res.params, truth)]
    cos = heading[0] @ heading[1] / np.linalg.norm(heading[0]) / np.linalg.norm(heading[1])
    assert cos > np.cos(np.radians(20.0)), res.label
    err = np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                         - joint_centre_array(model, forward(model, truth)), axis=1)
    assert err.mean() < 0.06


def _hop(frames: int):
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.retarget import retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    return retarget_bvh(load_bvh(bundled_motion("scaled_131_03")), frames=frames, start_s=0.0)


@pytest.mark.parametrize("k, gap", [(70, 5), (100, 8)])
def test_lost_hop_recovers_in_the_cheap_local_stage(k, gap):
    """The hop with ``gap`` frames dropped after the last good frame k (joints 14 and 22 cm from
    the last good pose on average): the local stage alone finds it (71 poses scored, ~0.2 s of one
    core; the full search scores ~440 and takes ~1.3 s) within 30 mm (measured 13 and 7 mm)."""
    mot = _hop(k + gap + 1)
    model, last, truth = mot.model, mot.params[k], mot.params[k + gap]
    cams = ring_cameras(4, size=(640, 480), start_deg=20.0)
    sils, chamfer = rendered_views(model, truth, cams)
    truth_joints = joint_centre_array(model, forward(model, truth))

    def error(p):
        return np.linalg.norm(joint_centre_array(model, forward(model, p)) - truth_joints, axis=1).mean()

    assert error(last) > 0.1
    res = recover(model, cams, sils, chamfer, last)
    assert res.label.startswith("local/") and res.candidates < 200, res.label
    assert res.score >= 0.87 and error(res.params) < 0.030
    options = TrackerOptions().recover_search
    assert recover(model, cams, sils, chamfer, last, options=options).label.startswith("local/")  # the Tracker's


def test_local_stage_falls_back_to_the_full_search():
    """A local result below ``accept_iou`` is not taken: the full search runs (and here finds the
    pose, measured 15 mm)."""
    mot = _hop(59)
    model, last, truth = mot.model, mot.params[50], mot.params[58]
    cams = ring_cameras(4, size=(640, 480), start_deg=20.0)
    sils, chamfer = rendered_views(model, truth, cams)
    res = recover(model, cams, sils, chamfer, last, options=SearchOptions.for_recovery(accept_iou=1.01))  # none reaches
    assert res.label.split("/")[0] in ("last", "hint", "T", "A", "T/A", "A/T") and res.candidates > 200
    err = np.linalg.norm(joint_centre_array(model, forward(model, res.params))
                         - joint_centre_array(model, forward(model, truth)), axis=1)
    assert err.mean() < 0.04


def test_rejoin_takes_the_first_sure_seed_and_skips_bad_ones():
    """``rejoin``: non-finite seeds are skipped; from a seed near the truth (the hop, 3 frames
    earlier) it returns a pose within 30 mm that reaches ``recover``'s own acceptance; a gate no
    pose can reach gives None (the caller then runs the full search)."""
    from tracker.search.recovery import rejoin

    mot = _hop(74)
    model, last, truth = mot.model, mot.params[70], mot.params[73]
    cams = ring_cameras(4, size=(640, 480), start_deg=20.0)
    sils, chamfer = rendered_views(model, truth, cams)
    truth_joints = joint_centre_array(model, forward(model, truth))
    bad = np.full(model.n_params, np.nan)
    res = rejoin(model, cams, sils, chamfer, [bad, last])
    assert res is not None and res.label.startswith("local/")
    assert np.linalg.norm(joint_centre_array(model, forward(model, res.params)) - truth_joints, axis=1).mean() < 0.03
    assert rejoin(model, cams, sils, chamfer, [bad]) is None
    assert rejoin(model, cams, sils, chamfer, [last], options=SearchOptions.for_recovery(accept_iou=1.01),
                  accept_iou=1.01) is None


def test_rejoin_refines_the_best_scoring_seed_first_and_stops_at_the_gate(monkeypatch):
    """``rejoin`` scores every seed's starts together and refines the best seed's first: with a
    stale seed (33 frames back) given before a near one (3 frames back) it returns what
    ``local_search`` from the near seed alone returns, bit for bit, with as many LM refinements
    (the stale seed is never refined); two equal seeds are refined once."""
    import tracker.search.recovery as rec
    from tracker.search.initialise import search_views
    from tracker.search.scoring import prepare_inputs

    mot = _hop(74)
    model, stale, near, truth = mot.model, mot.params[40], mot.params[70], mot.params[73]
    cams = ring_cameras(4, size=(640, 480), start_deg=20.0)
    sils, chamfer = rendered_views(model, truth, cams)
    options = SearchOptions.for_recovery()
    calls = []
    refine = rec.refine
    monkeypatch.setattr(rec, "refine", lambda *a, **k: calls.append(1) or refine(*a, **k))
    inputs = prepare_inputs(model, cams, sils, chamfer)
    hull, views = search_views(model, inputs, options, caller="test")
    accept = min(0.8, options.accept_iou, views.expected_iou() - options.iou_margin)
    alone = rec.local_search(model, inputs.cameras, inputs.chamfer, views, hull, model.clamp(near), accept_iou=accept,
                             mirror_check=options.front_back)
    n_alone = len(calls)
    assert alone is not None and n_alone >= 1
    calls.clear()
    res = rec.rejoin(model, cams, sils, chamfer, [stale, near], options=options, accept_iou=0.8)
    assert res is not None and np.array_equal(res.params, alone.params) and len(calls) == n_alone
    calls.clear()
    assert rec.rejoin(model, cams, sils, chamfer, [near, near.copy()], options=options, accept_iou=0.8) is not None
    assert len(calls) == n_alone
