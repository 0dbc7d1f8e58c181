"""The live track worker calibrates a subject of other proportions beside the stream and publishes it
(real zenoh sessions on loopback, multicast off; camera, segment and track workers as threads)."""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from capture.replay import ReplaySource
from capture.session import load_session
from service.backgrounds import background_models
from service.synthetic_session import make_proportioned_session
from service.wire.bus import Keys, wait_until_alive
from service.wire.records import PoseRecord
from service.wire.subject import SubjectMessage
from service.workers.auto_subject import AutoSubject
from service.workers.components import BackgroundSegmenter
from service.workers.live_fit import LiveTrackerFitter
from service.workers.loops import run_camera_worker, run_segment_worker, run_track_worker
from tests.support.workers import Studio, wait_for
from tracker.body.subject import read_subject
from tracker.fitting.subject_auto import AutoSubjectOptions
from tracker.fitting.subject_size import nominal_segment_lengths


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("CONTOURCAP_LIVE_CALIBRATION_TEST"),
                    reason="opt-in (CONTOURCAP_LIVE_CALIBRATION_TEST=1): whether the live calibration is sampled and "
                           "adopted within minutes depends on the live track and the load (passed in 240 s alone; not "
                           "adopted in 5 min in a full-suite run)")
def test_live_worker_calibrates_publishes_and_tracks_on(tmp_path):
    root, true = make_proportioned_session(tmp_path / "s", seed=0, frames=90, cameras=4, size=(240, 180),
                                           codec="png", n_background=5)
    session = load_session(root)
    names = tuple(session.camera_names)
    fit = LiveTrackerFitter.from_session(session)
    # the clip loops every 3 s: sets spaced by a fifth of it, sampled from 4 s of usable fits
    opts = AutoSubjectOptions(frames=7, held_out=2, offers=14, min_gap=18, rounds=1,
                              judge_rounds=2)
    # nice 0: on a loaded test machine a lowered thread may wait minutes (the priority is not under test)
    fit.auto_subject = AutoSubject(fit.tracker.model, list(fit.tracker.cameras.values()), opts,
                                   out_path=tmp_path / "subject_auto.toml", nice=0)
    backgrounds, _ = background_models(session, list(names))
    keys = Keys("autosubj")
    studio = Studio(keys)
    poses, states, subjects = [], [], []
    lock = threading.Lock()

    def on_pose(p):
        with lock:
            poses.append(p)
            states.append(fit.auto_subject.state.state)

    try:
        track_session = studio.session(listen=True)
        sub = studio.session().declare_subscriber(keys.subject, lambda s: subjects.append(
            SubjectMessage.from_bytes(bytes(s.payload.to_bytes()))))
        studio.start("track", run_track_worker, track_session, keys, names, fit, mode="live",
                     set_timeout_s=0.3, stop=studio.stop, on_pose=on_pose)
        studio.start("segment", run_segment_worker, studio.session(), keys,
                     {c: BackgroundSegmenter(model=backgrounds[c]) for c in names}, mode="live", stop=studio.stop)
        cam_session = studio.session()
        assert wait_until_alive(cam_session, keys, ("track", "segment"), timeout_s=20.0)
        sources = {c: ReplaySource(session, c, pacing="realtime", loop=True) for c in names}
        for s in sources.values():
            s.open()
        studio.start("camera", run_camera_worker, cam_session, keys, sources, mode="live", stop=studio.stop)
        # the subject published, then at least 20 poses tracked with it
        assert wait_for(lambda: (subjects and sum(p.get("subject") is not None for p in poses) >= 20)
                        or fit.auto_subject.state.state in ("rejected", "failed"), 600.0), \
            (len(poses), fit.auto_subject.state.state, getattr(fit.auto_subject.state.result, "iou_current", None),
             getattr(fit.auto_subject.state.result, "iou_calibrated", None))
        sub.undeclare()
    finally:
        studio.close()
    with lock:
        poses, states = list(poses), list(states)
    state = fit.auto_subject.state
    assert state.state == "adopted" and state.result.iou_calibrated > state.result.iou_current
    # the message validates and is the file the worker wrote
    assert subjects[0].subject == read_subject(tmp_path / "subject_auto.toml")
    for k, v in state.result.subject.segment_lengths.items():  # the file's values are rounded to 0.1 mm
        assert subjects[0].subject.segment_lengths[k] == pytest.approx(v, abs=1e-4)
    # frame order, once per frame, every record valid; sets complete while it calibrated
    frames = [p.frame for p in poses]
    assert frames == sorted(set(frames))
    assert all(isinstance(p, PoseRecord) and (p.ok or p.get("reason")) for p in poses)
    during = [p for p, s in zip(poses, states) if s == "fitting"]
    assert len(during) >= 5  # the stream went on while it calibrated
    assert sum(len(names) - p.get("cameras", 0) for p in during) <= 0.1 * len(during)
    # the records name the body from the swap on, and only from there
    named = [p.get("subject") is not None for p in poses]
    swap = named.index(True)
    assert all(named[swap:]) and all(p.get("subject") == "subject_auto.toml" for p in poses[swap:])
    # the calibrated lengths are nearer the rendered truth, and the poses after the swap are not worse
    nominal = nominal_segment_lengths(fit.tracker.model)
    cal = state.result.fit.segment_lengths
    assert np.mean([abs(cal[k] - true[k]) for k in true]) < np.mean([abs(nominal[k] - true[k]) for k in true])
    # the poses' error before and after the swap is not asserted here: on a loaded machine the live track's
    # lost and turned stretches dominate it (two runs: 175 -> 194 mm and 172 -> 87 mm over all records);
    # bench/auto_subject.py measures it on the same sets, deterministically (docs/subject_calibration.md)
