"""The live pipeline (issue 13): completeness of what it publishes, the demand's regions of interest,
adaptive effort, the gap-scaled prediction and `echo --stats`.  Properties, not timings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.commands.echo import PoseStats
from service.wire.messages import MessageError
from service.wire.records import DEMAND_MAX_ROIS, DemandMessage, PoseRecord
from service.workers.components import roi_clipped
from service.workers.live_fit import EFFORT_LEVELS, EffortController


def test_demand_rois_round_trip_and_bounds():
    msg = DemandMessage("track", 12, {"cam0": (1, 2, 30, 40), "cam1": (0, 0, 320, 240)})
    back = DemandMessage.from_bytes(msg.to_bytes())
    assert back.frame_id == 12 and dict(back.rois) == {"cam0": (1, 2, 30, 40), "cam1": (0, 0, 320, 240)}
    assert DemandMessage.from_bytes(DemandMessage("track", 3).to_bytes()).rois is None  # optional
    bad = [{"cam0": [5, 0, 3, 4]}, {"cam0": [0, 0, 1]}, {"cam0": [0, 0, 1.5, 2]}, {"cam0": [-1, 0, 4, 4]},
           {"cam0": [0, 0, 70000, 4]}, {"cam0": [True, 0, 4, 4]}, {"../x": [0, 0, 4, 4]}, [[0, 0, 4, 4]],
           {f"c{i}": [0, 0, 4, 4] for i in range(DEMAND_MAX_ROIS + 1)}]
    for rois in bad:
        data = json.dumps({"v": 1, "consumer": "track", "frame_id": 1, "rois": rois}).encode()
        with pytest.raises(MessageError):
            DemandMessage.from_bytes(data, max_bytes=1 << 16)


def test_roi_clipped_only_on_inner_sides():
    sil = np.zeros((40, 60), np.uint8)
    sil[10:20, 0:15] = 255  # touches the image's left border and x = 14
    assert not roi_clipped(sil, (0, 5, 30, 30), (60, 40))  # the left side is the image border
    assert roi_clipped(sil, (0, 5, 15, 30), (60, 40))  # the right side cuts the silhouette
    assert not roi_clipped(np.zeros((40, 60), np.uint8), (10, 10, 20, 20), (60, 40))


def test_effort_steps_down_when_behind_and_back_up():
    ctl = EffortController(1 / 30, window=3)
    levels = [ctl.update(0.050) for _ in range(9)]  # fits slower than the frame period
    assert levels[-1] == len(EFFORT_LEVELS) - 1 and levels == sorted(levels)
    levels = [ctl.update(0.005) for _ in range(9)]
    assert levels[-1] == 0 and levels == sorted(levels, reverse=True)
    for _ in range(9):
        ctl.update(0.050)
    assert ctl.level == len(EFFORT_LEVELS) - 1
    assert ctl.update(0.050, ok=False) == len(EFFORT_LEVELS) - 2  # a bad fit: more effort at once
    assert all(a.n_samples >= b.n_samples and a.max_iterations >= b.max_iterations
               for a, b in zip(EFFORT_LEVELS, EFFORT_LEVELS[1:]))


def test_prediction_scales_with_the_frame_gap():
    from capture.camera import Camera  # noqa: F401  (the tracker's import chain)
    from tracker.body.model import load_model
    from tracker.fitting.tracking import MAX_EXTRAPOLATION, Tracker
    from tracker.synthetic.scene import ring_cameras

    model = load_model("knossow40")
    tr = Tracker(model, ring_cameras(2, size=(80, 60)), initial_params=model.zero())
    p0 = model.zero()
    p1 = p0.copy()
    p1[0] += 0.02  # root x moved 2 cm between frames 10 and 12
    tr.previous, tr.params, tr._frames = p0, p1, (10, 12)
    assert tr.predict()[0] == pytest.approx(0.04)  # the next set: one step
    assert tr.predict(13)[0] == pytest.approx(0.03)  # half a step's frames
    assert tr.predict(16)[0] == pytest.approx(0.06)  # two steps
    assert tr.predict(1000)[0] == pytest.approx(0.02 + MAX_EXTRAPOLATION * 0.02)


def test_sets_are_demanded_sparsely_only_while_the_initialisation_searches():
    from tracker.body.model import load_model
    from tracker.fitting.tracking import Tracker
    from tracker.synthetic.scene import ring_cameras
    from service.workers.live_fit import LiveTrackerFitter

    class Runner:
        running = False

        def start(self, fn, name, then=None):
            self.running = True

        def busy(self):
            return self.running

    model = load_model("knossow40")
    tr = Tracker(model, ring_cameras(2, size=(80, 60)))
    runner = Runner()
    fit = LiveTrackerFitter(tr, search_runner=runner, initialise_demand_s=0.25)
    opts = fit.tracker.options  # the cheaper live searches
    assert not opts.initialise_search.limb_search_both and not opts.recover_search.limb_search_both
    assert opts.recover_search.keep == 2
    assert fit.demand_interval_s == 0.0  # no search yet: the first set starts it
    runner.running = True
    assert fit.demand_interval_s == 0.25  # initialising: nothing to fit the sets to
    tr.params = model.zero()
    assert fit.demand_interval_s == 0.0  # a recovery search: tracking goes on, every set is wanted
    runner.running, tr.params = False, None
    assert fit.demand_interval_s == 0.0


def test_no_search_starts_on_a_set_most_cameras_are_missing_from():
    """A set released before most cameras' chamfers came (start-up) would give the initialisation
    one view: it waits for a set with silhouettes from 3 of the 4 cameras."""
    from tracker.body.model import load_model
    from tracker.fitting.tracking import Tracker
    from tracker.synthetic.scene import ring_cameras
    from service.workers.live_fit import LiveTrackerFitter

    class Runner:
        def __init__(self):
            self.started = []

        def start(self, fn, name, then=None):
            self.started.append(name)

        def busy(self):
            return False

    tr = Tracker(load_model("knossow40"), ring_cameras(4, size=(80, 60)))
    runner = Runner()
    fit = LiveTrackerFitter(tr, search_runner=runner)
    body = np.zeros((60, 80), np.uint8)
    body[20:50, 30:40] = 255
    names = list(tr.cameras)
    for present, starts in ((names[:1], False), (names[:2], False), (names[:3], True), (names, True)):
        runner.started.clear()
        sils = {n: body for n in present} | {n: np.zeros_like(body) for n in names if n not in present}
        assert fit._start_search(0, None, {n: None for n in names}, sils) is starts
        assert runner.started == (["search-initialisation"] if starts else [])


def test_pose_stats_line():
    t = [0.0]
    stats = PoseStats(lambda: t[0])
    for i in range(11):
        t[0] = i * 0.1
        stats.add(PoseRecord.from_dict({"frame": i, "timestamp_ns": i, "ok": i % 2 == 0, "reason": "x",
                                        "latency_ms": 10.0 + i, "fit_ms": 5.0}))
    line = stats.line()
    assert "11 poses" in line and "10.0 poses/s" in line and "55 % ok" in line
    assert "latency p50 15.0 ms" in line and "fit p50 5.0 ms" in line


@pytest.mark.slow
def test_live_demo_publishes_complete_sets_in_order_with_latency(tmp_path):
    """The real live pipeline (camera, segment and track processes, the live fitter): every pose is
    of a complete set (or the gap is counted), in frame order, once per frame, with
    capture-to-publish latency and fit time."""
    pytest.importorskip("tracker.synthetic.synth")
    from service.demo import DemoOptions, run_demo
    from tracker.fitting.warmup import warm_up

    warm_up()  # fills numba's disk cache, which the track worker's own warm-up then loads
    opts = DemoOptions(cameras=3, size=(160, 120), frames=30, fps=30.0, out_dir=tmp_path / "out",
                       cache_dir=tmp_path / "cache", timeout_s=180.0, delivery="live",
                       live_start_delay_s=6.0, live_duration_s=6.0, live_image_cameras=0)
    summary = run_demo(opts, progress=lambda m: None)
    poses = [json.loads(line) for line in (tmp_path / "out" / "poses.jsonl").read_text().splitlines()]
    assert len(poses) >= 5, summary
    frames = [p["frame"] for p in poses]
    assert frames == sorted(set(frames))  # in frame order, never twice
    # every set complete (all cameras are up): a frame a loaded segment worker lost before segmenting it
    # (evicted from its ring) leaves that camera out of one set, and the tracker counts each such gap
    missing = sum(3 - p["cameras"] for p in poses)
    assert missing <= summary.missing_cameras and missing <= 0.1 * len(poses)
    for p in poses:
        assert p["latency_ms"] >= 0 and p["fit_ms"] >= 0
        assert p["ok"] or p["reason"]
        if "params" in p:
            assert "effort" in p or p["reason"].startswith("searching")
    assert summary.latency_ms_p50 is not None
    assert summary.replay_ns[0] < summary.replay_ns[1]  # the replay window (bench/pipeline.py's CPU split)
