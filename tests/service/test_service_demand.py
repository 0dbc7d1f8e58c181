"""Live mode on demand: have/demand records (validation, fuzz), the tracker's DemandPlanner and the
segment worker's FrameRing on injected clocks, and the live pipeline end to end on loopback zenoh
(every camera segments the demanded frame: complete sets, increasing frame ids, and only demanded
frames are segmented)."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from capture.replay import ReplaySource
from service.flow.demand import DemandPlanner, FrameRing, frame_header
from service.wire.messages import FrameMessage, MessageError
from service.wire.records import HAVE_MAX_FRAMES, DemandMessage, HaveMessage
from tests.support.messages import mutations as _mutations
from tests.support.workers import CAMS, fitter, make_session, segmenter, wait_for  # noqa: F401


# --- records -------------------------------------------------------------------------------------

def test_have_and_demand_round_trip_and_validation():
    have = HaveMessage("cam0", (5, 6, 7))
    assert HaveMessage.from_bytes(have.to_bytes()) == have and have.newest == 7
    assert HaveMessage.from_bytes(HaveMessage("cam0", ()).to_bytes()).newest is None
    demand = DemandMessage("track", 41)
    assert DemandMessage.from_bytes(demand.to_bytes()) == demand
    bad_have = [b'{"v": 1, "camera": "cam0", "frames": [1, -2]}', b'{"v": 1, "camera": "cam0", "frames": [1.5]}',
                b'{"v": 1, "camera": "cam0", "frames": [true]}', b'{"v": 1, "camera": "../x", "frames": []}',
                b'{"v": 2, "camera": "cam0", "frames": []}', b'{"v": 1, "camera": "cam0", "frames": 3}',
                b'{"v": 1, "camera": "cam0", "frames": [' + b",".join(b"1" for _ in range(HAVE_MAX_FRAMES + 1)) + b"]}",
                b'{"v": 1, "camera": "cam0", "frames": [NaN]}', b" " * 5000]
    for data in bad_have:
        with pytest.raises(MessageError):
            HaveMessage.from_bytes(data)
    for data in (b'{"v": 1, "consumer": "track", "frame_id": -1}', b'{"v": 1, "consumer": "", "frame_id": 1}',
                 b'{"v": 1, "consumer": "track"}', b'{"consumer": "track", "frame_id": 1}', b"[]"):
        with pytest.raises(MessageError):
            DemandMessage.from_bytes(data)


@pytest.mark.parametrize("msg", [HaveMessage("cam0", tuple(range(100, 108))), DemandMessage("track", 12345)])
def test_fuzz_have_and_demand_raise_only_message_error(msg):
    rng = np.random.default_rng(11)
    data = msg.to_bytes()
    accepted = rejected = 0
    for _ in range(200):
        for bad in _mutations(data, rng):
            for cls in (HaveMessage, DemandMessage):
                try:
                    cls.from_bytes(bad)
                except MessageError:
                    rejected += 1
                else:
                    accepted += 1
    assert rejected > 0 and accepted < rejected


# --- FrameRing (segment worker side) --------------------------------------------------------------

def _frame_bytes(camera, fid, rng):
    return FrameMessage.from_image(camera, fid, fid * 40_000_000,
                                   rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)).to_bytes()


def test_frame_ring_keeps_newest_undecoded_and_resolves_demands(rng):
    ring = FrameRing("cam0", size=4)
    for fid in range(10, 16):
        assert ring.put(_frame_bytes("cam0", fid, rng), fid) == fid
    assert ring.take_news() == (12, 13, 14, 15) and ring.take_news() is None and ring.evicted == 2
    assert frame_header(_frame_bytes("cam0", 3, rng)) == ("cam0", 3)
    with pytest.raises(MessageError):
        ring.put(_frame_bytes("cam1", 16, rng), None)  # another camera's frame on this key
    with pytest.raises(MessageError):
        ring.put(b"CCAP" + bytes(40), None)
    ring.demand(13, 0.0)
    ring.demand(11, 0.0)  # evicted: missed
    ring.demand(20, 0.0)  # not arrived yet: waits
    with ring.cv:
        assert ring.busy()
    missed, got = ring.next_demanded(0.1, wait_s=0.5)
    assert missed == [] and got[0] == 13 and got[2] == 13
    assert FrameMessage.from_bytes(got[1]).frame_id == 13  # the bytes as received
    assert len(ring) == 2 and ring.skipped == 1  # taken out of the ring, and the older 12 with it
    missed, got = ring.next_demanded(0.1, wait_s=0.5)
    assert missed == [11] and got is None
    with ring.cv:
        assert not ring.busy()  # only a demand waiting for its frame: nothing to do but wait
    ring.put(_frame_bytes("cam0", 20, rng), None)
    missed, got = ring.next_demanded(0.2, wait_s=0.5)
    assert missed == [] and got[0] == 20
    ring.demand(30, 1.0)
    assert ring.next_demanded(1.4, wait_s=0.5) == ([], None)
    assert ring.next_demanded(1.6, wait_s=0.5) == ([30], None)  # never arrived: given up


# --- DemandPlanner (tracker side) -----------------------------------------------------------------

def test_planner_demands_the_newest_frame_every_live_camera_holds():
    p = DemandPlanner(("a", "b", "c"), absent_after_s=0.5, startup_grace_s=0.5, demand_timeout_s=0.25)
    assert p.next_demand(0.0) is None
    p.have("a", (1, 2, 3, 4), 0.0)
    p.have("b", (1, 2, 3, 4), 0.0)
    assert p.next_demand(0.1) is None  # c not heard yet, within the start-up grace
    p.have("c", (1, 2, 3), 0.1)  # c is one frame behind (and b skipped nothing)
    assert p.next_demand(0.1) == 3  # held by all three, not 4 (held by two)
    assert p.outstanding[0] == 3 and p.wanted(3) and not p.wanted(4)
    p.have("c", (1, 2, 3, 4, 5), 0.12)
    p.have("a", (2, 3, 4, 5), 0.12)
    p.have("b", (2, 3, 4, 5), 0.12)
    assert p.next_demand(0.12) is None  # one demand outstanding
    p.released(3)
    assert p.next_demand(0.13) == 5  # the next set, while 3 is fitted
    p.released(5)
    p.have("a", (7, 8, 9), 0.2)
    p.have("b", (6, 8, 9), 0.2)
    p.have("c", (6, 7, 8), 0.2)  # skipped frames differ per camera: 8 is the newest all hold
    assert p.next_demand(0.2) == 8
    # the demand is lost: after demand_timeout_s a new one goes out (unless its set is being assembled)
    p.have("a", (9, 10), 0.3)
    p.have("b", (9, 10), 0.3)
    p.have("c", (9, 10), 0.3)
    assert p.next_demand(0.4, hold=lambda fid: fid == 8) is None
    assert p.next_demand(0.46) == 10 and p.timeouts == 1


def test_planner_waits_briefly_for_a_complete_set_then_goes_on_without():
    p = DemandPlanner(("a", "b"), partial_wait_s=0.1)
    p.have("a", (1,), 0.0)
    p.have("b", (1,), 0.0)
    assert p.next_demand(0.0) == 1
    p.released(1)
    p.have("a", (1, 2), 0.01)  # frame 2 was lost on its way to b's segment worker
    assert p.next_demand(0.02) is None
    p.have("a", (1, 2, 3), 0.05)
    p.have("b", (1, 3), 0.05)
    assert p.next_demand(0.05) == 3  # complete: at once
    p.released(3)
    p.have("a", (1, 2, 3, 4), 0.08)
    assert p.next_demand(0.09) is None and p.next_demand(0.15) is None
    assert p.next_demand(0.2) == 4  # b did not get 4 within partial_wait_s: the set goes on without it


def test_planner_leaves_out_a_dead_camera_and_takes_it_back():
    p = DemandPlanner(("a", "b"), absent_after_s=0.5, demand_timeout_s=0.25)
    p.have("a", (1,), 0.0)
    p.have("b", (1,), 0.0)
    assert p.next_demand(0.0) == 1
    p.released(1)
    for k, t in enumerate((0.1, 0.2, 0.3, 0.4, 0.7)):
        p.have("a", (2 + k,), t)  # b has stopped
    assert p.live(0.7) == ("a",)
    assert p.next_demand(0.7) == 6  # without b, not stuck at b's last frame
    p.released(6)
    p.have("b", (7,), 0.75)
    p.have("a", (7,), 0.75)
    assert p.live(0.75) == ("a", "b") and p.next_demand(0.75) == 7


def test_planner_follows_a_restarted_numbering_and_ignores_unknown_cameras():
    p = DemandPlanner(("a",), restart_gap=8)
    p.have("a", (500, 501), 0.0)
    assert p.next_demand(0.0) == 501
    p.released(501)
    assert not p.have("x", (1000,), 0.0) and p.unknown == 1
    p.have("a", (0, 1), 1.0)  # the trigger box reopened: ids from 0 again
    assert p.restarts == 1 and p.next_demand(1.0) == 1


# --- end to end -----------------------------------------------------------------------------------

def test_live_pipeline_delivers_complete_sets_and_segments_only_demanded_frames(tmp_path, rng, studio):
    """Three cameras replayed in real time (40 ms frames) to a tracker that takes 60 ms per fit: it
    cannot take every frame; it demands the newest frame all cameras hold, every camera segments
    that frame, so every set is complete and frame ids increase; frames never demanded are never
    segmented."""
    session = make_session(tmp_path / "s", rng, n_frames=60)  # 2.4 s at 25 fps
    segmented = []
    lock = threading.Lock()

    def slow_fitter(frame_id, timestamp_ns, chamfer):
        threading.Event().wait(0.06)
        return fitter(frame_id, timestamp_ns, chamfer)

    def counting_segmenter(frame, image):
        with lock:
            segmented.append((frame.camera, frame.frame_id))
        return segmenter(frame, image)

    poses, cam_stats = studio.run_live(session, slow_fitter, counting_segmenter)
    assert cam_stats["processed"] == 3 * 60
    assert wait_for(lambda: poses and poses[-1].frame == 59, 5.0)  # the last frame is demanded too
    frames = [p.frame for p in poses]
    assert frames == sorted(set(frames))
    assert 10 <= len(poses) <= 45  # ~(2.4 s - 0.5 s start-up) / 60 ms; far fewer than the 60 frames
    incomplete = [(p.frame, p.get("cameras")) for p in poses if p.get("cameras") != 3]
    if incomplete:
        studio.stop.set()
        for t in studio.threads:
            t.join(5.0)
    assert not incomplete, (incomplete, studio.results)
    offline = {f: fitter(f, 0, {c: segmenter(*_replayed(session, c, f)) for c in CAMS})["params"] for f in frames}
    assert all(p.to_dict()["params"] == offline[p.frame] for p in poses)  # each camera segmented frame p.frame
    with lock:
        done = list(segmented)
    assert sorted(set(done)) == sorted(done)  # no frame segmented twice
    assert {f for _, f in done} <= set(frames) | {f for f in range(60) if f > frames[-1] - 3}
    assert len(done) <= 3 * len(frames) + 6


def _replayed(session, camera, fid):
    src = ReplaySource(session, camera)
    src.open()
    try:
        while True:
            fr = src.read()
            if fr.frame_id == fid:
                return FrameMessage.from_image(camera, fid, fr.timestamp_ns, fr.image), fr.image
    finally:
        src.close()


def test_live_track_worker_does_not_take_a_long_fit_for_idleness(tmp_path, rng, studio):
    """A fit longer than idle_exit_s (a re-initialisation takes seconds) is not idleness: the worker
    goes on while the cameras stream, and exits once they stop."""
    session = make_session(tmp_path / "s", rng, n_frames=40)  # 1.6 s

    def slow_fitter(frame_id, timestamp_ns, chamfer):
        threading.Event().wait(0.3)
        return fitter(frame_id, timestamp_ns, chamfer)

    poses, _ = studio.run_live(session, slow_fitter, segmenter, idle_exit_s=0.2)
    assert wait_for(lambda: "track" in studio.results, 5.0)  # exited after the stream ended
    assert len(poses) >= 3 and poses[-1].frame >= 30, [p.frame for p in poses]

