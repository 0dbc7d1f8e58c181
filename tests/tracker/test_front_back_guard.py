"""The tracker's front/back guard (tracker.fitting.hypotheses) on direct renders of the model."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from segmentation.distance import chamfer_images
from tracker.body.kinematics import forward, joint_centre_array
from tracker.body.model import load_model
from tracker.fitting.hypotheses import FrontBackGuard
from tracker.fitting.tracking import Tracker
from tracker.imaging.render import internal_edges, render_label_images
from tracker.search.mirror import mirror_params
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.retarget import retarget_bvh
from tracker.synthetic.scene import ring_cameras

HOP = Path(__file__).resolve().parents[2] / "tracker" / "synthetic" / "data" / "scaled_131_03.bvh"


def _render(model, params, cameras):
    labels = render_label_images(model, forward(model, params), cameras)
    sils = {c.name: np.where(lab >= 0, 255, 0).astype(np.uint8) for c, lab in zip(cameras, labels)}
    chamfer = {c.name: chamfer_images(sils[c.name], internal_edges(lab)) for c, lab in zip(cameras, labels)}
    return chamfer, sils


def _errors_mm(model, records, truth):
    out = []
    for rec, p in zip(records, truth):
        jc = joint_centre_array(model, forward(model, np.asarray(rec["params"])))
        out.append(1e3 * np.linalg.norm(jc - joint_centre_array(model, forward(model, p)), axis=1).mean())
    return np.array(out)


def _standing(model, n: int, seed: int) -> np.ndarray:
    """A T-pose at a random place and heading lowering its arms to 60° below horizontal over ``n`` frames."""
    rng = np.random.default_rng(seed)
    p = model.zero()
    p[:2] = rng.uniform(-0.5, 0.5, 2)
    p[5] = rng.uniform(-np.pi, np.pi)
    arms = [model.param_index(f"{s}_upper_arm.abduction") for s in ("left", "right")]
    out = np.repeat(p[None], n, axis=0)
    out[:, arms] = np.radians(-60.0) * np.linspace(0.0, 1.0, n)[:, None]
    return out


def test_a_track_started_turned_round_is_reopened_and_turned_back():
    """A standing subject tracked from the mirror of the truth (as a wrong initialisation would
    start it), recovery off: the pose fits the silhouettes as well as the truth, but its feet point
    backwards; the guard flags the frames, re-opens the question, tracks the mirror beside the pose
    and takes it."""
    model, cams = load_model("knossow40"), ring_cameras(4, size=(320, 240))
    truth = _standing(model, 16, seed=3)
    tracker = Tracker(model, cams, initial_params=mirror_params(model, truth[0]), recover=False)
    assert tracker.guard.state == "resolved"  # a given start pose is trusted ...
    records = [tracker.step(k, int(k * 1e9 / 30), *_render(model, p, cams)) for k, p in enumerate(truth)]
    errs = _errors_mm(model, records, truth)
    assert tracker.guard.n_reopened >= 1 and tracker.n_turned >= 1  # ... until the evidence turns against it
    assert errs[:2].min() > 100.0 and errs[-4:].max() < 20.0, errs.round()
    # the given start is trusted until the evidence against it mounts (2 frames here), then no
    # turned frame is ok
    assert not any(r["ok"] for r, e in zip(records[2:], errs[2:]) if e > 100.0), \
        [(r["ok"], round(e)) for r, e in zip(records, errs)]


def test_the_guard_resolves_an_automatic_start_quickly():
    """From an automatic initialisation on renders of the model itself, the question is settled
    within 3 frames and the frames after are ok."""
    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=5, start_s=0.5, fps=30)
    model, cams = rt.model, ring_cameras(4, size=(320, 240))
    tracker = Tracker(model, cams)
    assert isinstance(tracker.guard, FrontBackGuard) and tracker.guard.state == "ambiguous"
    records = [tracker.step(k, int(k * 1e9 / 30), *_render(model, p, cams)) for k, p in enumerate(rt.params)]
    states = [r["front_back"] for r in records]
    assert "resolved" in states[:3], states
    assert all(r["ok"] for r in records[3:]), [r.get("reason") for r in records]
    assert all("front/back ambiguous" in r["reason"] for r in records if not r["ok"])
    assert _errors_mm(model, records, rt.params)[2:].max() < 30.0


def test_the_first_mirror_weighed_after_a_search_is_the_searchs_refined_one():
    """The initialisation refines its pose and that pose's mirror fully (``resolve_front_back``); the
    guard's first comparison starts the mirror's fit from that refined mirror (``offer_mirror``), not from
    the mirror of the pose fitted once, so both hypotheses are weighed as far refined."""
    from tracker.search.mirror import pelvis_heading

    rt = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1, start_s=0.5, fps=30)
    model, cams = rt.model, ring_cameras(4, size=(320, 240))
    tracker = Tracker(model, cams)
    starts = []
    ambiguous = tracker.guard._ambiguous

    def spy(t_s, cams_, chs, images, res, terms, fit, iou):
        def recorded(start, prediction, *more):
            starts.append(np.array(start))
            return fit(start, prediction, *more)
        return ambiguous(t_s, cams_, chs, images, res, terms, recorded, iou)

    tracker.guard._ambiguous = spy
    offers = []
    offer = tracker.guard.offer_mirror
    tracker.guard.offer_mirror = lambda params: (offers.append(params), offer(params))
    record = tracker.step(0, 0, *_render(model, rt.params[0], cams))
    assert len(offers) == 1 and offers[0] is not None and starts
    offered = offers[0]
    np.testing.assert_allclose(starts[0], offered)
    # the other hypothesis: turned round against the pose found
    assert pelvis_heading(model, np.asarray(record["params"])) @ pelvis_heading(model, offered) < -0.5


def test_an_open_question_reports_the_hypothesis_its_evidence_favours():
    """A standing subject tracked from the mirror of the truth, recovery off: once the question is
    re-opened, every frame while it is open reports the hypothesis its evidence sum favours (the mirror,
    here the truth, when the sum is negative) while the track goes on from the pose until the margin is
    reached; a frame with a non-negative sum reports the pose."""
    model, cams = load_model("knossow40"), ring_cameras(4, size=(320, 240))
    truth = _standing(model, 16, seed=3)
    tracker = Tracker(model, cams, initial_params=mirror_params(model, truth[0]), recover=False)
    records, tracked = [], []
    for k, p in enumerate(truth):
        records.append(tracker.step(k, int(k * 1e9 / 30), *_render(model, p, cams)))
        tracked.append(np.array(tracker.params))
    errs = _errors_mm(model, records, truth)
    errs_tracked = _errors_mm(model, [{"params": p} for p in tracked], truth)
    open_frames = [k for k, r in enumerate(records) if r["front_back"] == "ambiguous"]
    assert open_frames, [r["front_back"] for r in records]
    favoured = [k for k in open_frames if records[k]["front_back_cues"]["sum"] < 0]
    assert favoured, [records[k]["front_back_cues"] for k in open_frames]
    for k in open_frames:
        assert (records[k].get("front_back_reported") == "mirror") == (k in favoured)
        assert not records[k]["ok"]
    # the mirror reported is the truth; the tracked pose is still the turned one
    assert errs[favoured].max() < 30.0 and errs_tracked[favoured].min() > 100.0, (errs.round(), errs_tracked.round())
    assert not any("front_back_reported" in r for r in records if r["front_back"] == "resolved")
    for k in favoured:  # the record's joints and quality figures are those of the params it reports
        joints = joint_centre_array(model, forward(model, np.asarray(records[k]["params"])))
        np.testing.assert_allclose([records[k]["joints"][n] for n in model.joint_names], joints, atol=1e-9)
        assert "the mirror reported" in records[k]["reason"] and 0.0 < records[k]["iou"] <= 1.0
