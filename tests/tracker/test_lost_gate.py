"""The IoU gate's two jobs apart: a frame below ``min_iou`` is not ok, but only an IoU well below
what this body reaches (``TrackerOptions.lost_iou_margin``) counts towards a lost track."""

from __future__ import annotations

import numpy as np
import pytest

from tests.tracker.test_tracking import HOP, hop_scene, render_chamfer
from tracker.body.kinematics import forward, joint_centre_array
from tracker.fitting.tracking import Tracker, TrackerOptions
from service.wire.records import PoseRecord
from tracker.search.candidates import turn_about_vertical
from tracker.synthetic.bvh import load_bvh
from tracker.synthetic.retarget import retarget_bvh
from tracker.synthetic.scene import ring_cameras


@pytest.fixture(scope="module")
def scene():
    cameras, model, p0, ch, sil = hop_scene()
    return cameras, model, p0, (ch, sil)


def test_a_body_below_min_iou_is_not_ok_but_not_lost(scene):
    # min_iou above what the fit reaches (~0.9 on its own render at half resolution) stands for a
    # non-model body: every frame is reported not ok, the track is never searched again
    cameras, model, p0, (ch, sil) = scene
    soft = TrackerOptions(min_iou=0.99, lost_iou_margin=0.04)
    tracker = Tracker(model, cameras, initial_params=p0, patience=2, options=soft)
    recs = [tracker.step(k, k, ch, sil) for k in range(6)]
    assert not any(r["ok"] for r in recs)
    assert all("silhouette IoU" in r["reason"] and r["failed"] == ["iou"] for r in recs)
    assert all(PoseRecord.from_dict(r).get("failed") == ["iou"] for r in recs)  # a valid pose record field
    assert tracker.n_initialisations == 0
    assert 0.8 < tracker.lost_iou_limit() < 0.99
    assert tracker.last_good is not None  # the frames were kept for tracking

    # the old single gate: the same frames make the track lost and searched
    strict = Tracker(model, cameras, initial_params=p0, patience=2,
                     options=TrackerOptions(min_iou=0.99, lost_iou_margin=None))
    [strict.step(k, k, ch, sil) for k in range(4)]
    assert strict.n_initialisations >= 1


def test_an_iou_drop_below_the_reference_counts_towards_lost(scene):
    # after frames at the body's usual IoU, a jump the local fit cannot follow drops the IoU far
    # below that reference: those frames count, and the track is searched again
    cameras, model, p0, (ch, sil) = scene
    p1 = turn_about_vertical(model, p0, np.pi / 2, joint_centre_array(model, forward(model, p0))[0])
    p1[:2] += [0.6, -0.5]
    ch1, sil1 = render_chamfer(model, p1, cameras)
    soft = TrackerOptions(min_iou=0.99, lost_iou_margin=0.04)
    tracker = Tracker(model, cameras, initial_params=p0, patience=2, options=soft)
    [tracker.step(k, k, ch, sil) for k in range(3)]
    reference = tracker.lost_iou_limit()
    recs = [tracker.step(k, k, ch1, sil1) for k in range(3, 7)]
    assert recs[0]["iou"] < reference
    assert tracker.n_initialisations >= 1


def test_without_a_reference_the_floor_applies():
    opts = TrackerOptions(lost_iou_margin=0.04)
    assert opts.lost_iou_floor < opts.min_iou
    model = retarget_bvh(load_bvh(HOP), model="knossow40", frames=1).model
    tracker = Tracker(model, ring_cameras(2, size=(64, 48)), options=opts)
    assert tracker.lost_iou_limit() == pytest.approx(opts.lost_iou_floor)
    # the default: every IoU failure counts towards lost (round-1 behaviour)
    assert Tracker(model, ring_cameras(2, size=(64, 48))).lost_iou_limit() == TrackerOptions().min_iou


def test_an_rms_jump_triggers_the_iou_check(scene):
    # silhouettes of a body 20 % larger than the model: the fit's RMS triples (0.45 -> ~1.4 px) but
    # stays far below the RMS limit (6 px); the jump makes the IoU render run, and the IoU fails
    from tracker.body.model import load_model

    cameras, model, p0, (ch, sil) = scene
    big = load_model("knossow40", height_m=1.2 * model.height_m)
    ch2, sil2 = render_chamfer(big, p0, cameras)
    for jump, expect_checked in ((1.5, True), (None, False)):
        # the limb check off: its coverage limit would flag the larger body too (test_limbs.py)
        tracker = Tracker(model, cameras, initial_params=p0,
                          options=TrackerOptions(iou_every=100, iou_rms_jump=jump, limb_every=0))
        first = [tracker.step(k, k, ch, sil) for k in range(4)]
        assert ["iou" in r for r in first] == [True, False, False, False]
        after = tracker.step(4, 4, ch2, sil2)
        assert after["rms_px"] < 0.75 * tracker.rms_limit()
        assert ("iou" in after) is expect_checked
        assert after["ok"] is not expect_checked
