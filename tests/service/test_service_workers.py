"""Workers end to end on loopback zenoh (threads, one session each): lossless replay gives exactly the
offline result; live mode with a camera gone keeps publishing with fewer cameras; assembler rules."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from capture.replay import ReplaySource, iter_frame_sets
from capture.sources import Frame, StreamLostError
from capture.sync import FrameSetAssembler
from service.wire.bus import (
    Inbox,
    declare_publisher,
    free_port,
    wait_until_matched,
)
from service.wire.messages import FrameMessage
from service.wire.records import DemandMessage, PoseRecord
from service.workers.loops import WorkerError, run_camera_worker, run_segment_worker, run_track_worker
from tests.support.workers import CAMS, Studio, fitter, make_session, segmenter, wait_for  # noqa: F401


def test_lossless_replay_equals_offline(tmp_path, rng, studio):
    session = make_session(tmp_path / "s", rng)
    offline = [fitter(fid, next(iter(fr.values())).timestamp_ns,
                      {c: segmenter(FrameMessage.from_image(c, fid, f.timestamp_ns, f.image), f.image)
                       for c, f in fr.items()})
               for fid, fr in iter_frame_sets(session)]
    keys, poses = studio.keys, []
    track_s = studio.session(listen=True)
    client = studio.session()
    pose_inbox = Inbox(client, keys.pose, PoseRecord.from_bytes, mode="lossless", depth=1000)
    niceness = []  # the fitting thread's, at each fit

    def nice_fitter(*args):
        niceness.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
        return fitter(*args)

    studio.start("track", run_track_worker, track_s, keys, CAMS, nice_fitter, mode="lossless", stop=studio.stop,
                 max_frames=len(offline), on_pose=poses.append, priority_boost=2)
    studio.start("segment", run_segment_worker, studio.session(), keys, {c: segmenter for c in CAMS},
                 mode="lossless", stop=studio.stop)
    sources = {c: ReplaySource(session, c) for c in CAMS}
    for s in sources.values():
        s.open()
    cam_stats = run_camera_worker(studio.session(), keys, sources, mode="lossless", window=2,
                                  encodings={"cam0": "png", "cam1": "raw", "cam2": "png"}, stop=studio.stop,
                                  credit_timeout_s=10.0, startup_timeout_s=10.0)
    studio.threads[0].join(10.0)
    assert cam_stats["processed"] == 3 * len(offline)
    assert [p.to_dict()["params"] for p in poses] == [o["params"] for o in offline]
    assert [p.frame for p in poses] == [o["frame"] for o in offline]
    assert all(p.get("latency_ms") > 0 for p in poses)
    # the fit's thread CPU time: never more than its wall time (1 ms for the clocks' resolution)
    assert all(0 <= p.get("fit_cpu_ms") <= p.get("fit_ms") + 1.0 for p in poses)
    # the fitting thread ran 2 nice levels above the process, or the worker said it could not
    base = os.getpriority(os.PRIO_PROCESS, 0)
    assert niceness == [base - 2] * len(offline) or (studio.results["track"].get("priority_refused")
                                                      and niceness == [base] * len(offline))
    got = []
    assert wait_for(lambda: got.extend(pose_inbox.drain()) or len(got) >= len(offline), 5.0)
    assert [r.message.frame for r in got] == [o["frame"] for o in offline]


def test_live_missing_camera_lowers_cameras(tmp_path, rng, studio):
    """Live (demand-driven) with cam2 down: after the start-up grace (0.5 s without cam2's have notices)
    the tracker demands the frames cam0 and cam1 hold and keeps publishing with two cameras."""
    session = make_session(tmp_path / "s", rng, n_frames=40)  # 1.6 s at 25 fps (the grace is 0.5 s)
    poses, _ = studio.run_live(session, fitter, segmenter, cameras=CAMS[:2])  # cam2 is down
    assert wait_for(lambda: poses and poses[-1].frame == 39, 5.0)  # the last frame is demanded too
    assert len(poses) >= 8
    assert all(p.to_dict()["params"][2] == -1.0 for p in poses)  # cam2 never contributed
    frames = [p.frame for p in poses]
    assert frames == sorted(set(frames))  # live: newest only, never backwards, never twice
    # the tracker kept publishing without cam2, every set with both live cameras (they segment the demanded id)
    assert sum(p.get("cameras") == 2 for p in poses) >= 0.9 * len(poses)
    # and each record names the camera it went without
    assert all(p.get("missing_cameras") == ["cam2"] for p in poses if p.get("cameras") == 2)


def test_assembler_rules():
    asm = FrameSetAssembler(("a", "b"), mode="live", timeout_s=0.1, absent_after_s=1.0)
    asm.add("a", 1, "a1", 0.0)
    assert asm.pop_ready(0.01) == []
    asm.add("b", 1, "b1", 0.02)
    (fs,) = asm.pop_ready(0.02)
    assert fs.frame_id == 1 and fs.missing == ()
    asm.add("a", 2, "a2", 0.03)
    asm.add("a", 3, "a3", 0.04)
    asm.add("b", 3, "b3", 0.05)  # b skipped 2: set 2 is complete too, but 3 is newer
    (fs,) = asm.pop_ready(0.05)
    assert fs.frame_id == 3 and asm.stale == 1
    asm.add("a", 2, "late", 0.06)
    assert asm.late == 1
    asm.add("a", 4, "a4", 0.1)  # b falls silent
    assert asm.pop_ready(0.15) == []
    (fs,) = asm.pop_ready(0.21)
    assert fs.timed_out and fs.missing == ("b",)
    asm.add("a", 5, "a5", 2.0)  # b absent for > 1 s: a alone completes a set at once
    (fs,) = asm.pop_ready(2.0)
    assert fs.frame_id == 5 and not fs.timed_out and fs.missing == ("b",)
    asm.add("b", 6, "b6", 2.1)  # b rejoins: set 6 waits for a
    assert asm.pop_ready(2.1) == []


def test_assembler_live_accepts_a_restarted_numbering():
    """The trigger box reopened (camera worker restarted): ids start again from 0; sets go on."""
    asm = FrameSetAssembler(("a", "b"), mode="live", timeout_s=0.1, absent_after_s=1.0)
    for fid in (500, 501):
        asm.add("a", fid, "a", 0.0)
        asm.add("b", fid, "b", 0.0)
    assert [fs.frame_id for fs in asm.pop_ready(0.0)] == [501]
    asm.add("a", 502, "a", 0.01)  # pending set of the old numbering; then both restart
    asm.add("a", 0, "a0", 1.0)
    asm.add("b", 0, "b0", 1.0)
    (fs,) = asm.pop_ready(1.0)
    assert fs.frame_id == 0 and fs.missing == () and asm.restarts == 2 and asm.late == 0
    asm.add("a", 1, "a1", 1.04)
    asm.add("b", 1, "b1", 1.04)
    assert [fs.frame_id for fs in asm.pop_ready(1.04)] == [1]
    asm.add("b", 0, "late", 1.05)  # a few back: a late message, not a restart
    assert asm.late == 1 and asm.restarts == 2


def test_assembler_memory_is_bounded_against_a_flood_of_ids():
    asm = FrameSetAssembler(("a", "b"), mode="lossless", timeout_s=5.0, max_pending=16)
    for fid in range(1000):  # a rogue peer: a new frame id per message, never completed
        asm.add("a", fid, "x", 0.0)
    assert len(asm) == 16 and asm.overflow == 1000 - 16
    asm.add("b", 999, "b", 0.0)
    assert [fs.frame_id for fs in asm.pop_ready(5.1)][-1] == 999


def test_assembler_lossless_in_order():
    asm = FrameSetAssembler(("a", "b"), mode="lossless", timeout_s=1.0)
    for fid in (1, 2, 3):
        asm.add("a", fid, f"a{fid}", 0.0)
    asm.add("b", 2, "b2", 0.0)  # b skipped 1 (dropped frame in the session)
    assert [fs.frame_id for fs in asm.pop_ready(0.0)] == [1, 2]
    asm.add("b", 3, "b3", 0.1)
    assert [(fs.frame_id, fs.missing) for fs in asm.pop_ready(0.1)] == [(3, ())]


def _garbage(keys, rng):
    """(key, payload) pairs: random bytes, truncations, wrong versions, oversized, hostile JSON."""
    img = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    frame = bytearray(FrameMessage.from_image("cam0", 0, 0, img).to_bytes())
    old = bytes(frame[:5]) + b"\x02" + bytes(frame[6:])  # version 2
    out = []
    for key in (keys.frame("cam0"), keys.chamfer("cam0"), keys.pose, keys.credit("track"), keys.status("x")):
        out += [(key, rng.bytes(64)), (key, bytes(frame[:40])), (key, old), (key, b'{"v": 1, "frame_id": NaN}'),
                (key, b"[" * 10_000), (key, b'{"consumer": "track", "frame_id": -5, "v": 1}')]
    out.append((keys.pose, b" " * (2 * 1024 * 1024)))  # over the pose size limit
    return out


def test_garbage_on_every_key_is_counted_and_workers_live_on(tmp_path, rng, studio):
    session = make_session(tmp_path / "s", rng, n_frames=8)
    keys, poses = studio.keys, []
    rogue = studio.session(listen=True)
    pubs = {}
    stop_rogue = threading.Event()

    def inject():
        garbage = _garbage(keys, np.random.default_rng(7))
        while not stop_rogue.is_set():
            for key, payload in garbage:
                pubs.setdefault(key, rogue.declare_publisher(key)).put(payload)
            time.sleep(0.01)

    studio.start("track", run_track_worker, studio.session(), keys, CAMS, fitter, mode="lossless",
                 stop=studio.stop, max_frames=8, on_pose=poses.append)
    studio.start("segment", run_segment_worker, studio.session(), keys, {c: segmenter for c in CAMS},
                 mode="lossless", stop=studio.stop)
    injector = threading.Thread(target=inject, daemon=True)
    injector.start()
    sources = {c: ReplaySource(session, c) for c in CAMS}
    for s in sources.values():
        s.open()
    try:
        run_camera_worker(studio.session(), keys, sources, mode="lossless", window=2, stop=studio.stop,
                          credit_timeout_s=10.0, startup_timeout_s=10.0)
        studio.threads[0].join(10.0)
    finally:
        stop_rogue.set()
        injector.join(5)
        studio.stop.set()
        studio.threads[1].join(5)
    assert [p.frame for p in poses] == list(range(8))  # every frame, in order, despite the garbage
    track, segment = studio.results["track"], studio.results["segment"]
    assert track["bad"] > 0 and segment["bad"] > 0
    assert track["processed"] == 8 and segment["processed"] == 3 * 8


class _UnpluggedCamera:
    """A Source that delivers two frames, then loses its device (as a USB camera pulled out does)."""

    name = "cam0"

    def __init__(self):
        self.n = 0

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def read(self) -> Frame:
        if self.n >= 2:
            raise StreamLostError("camera cam0: device lost")
        self.n += 1
        return Frame("cam0", self.n, self.n * 40_000_000, np.zeros((30, 40, 3), np.uint8))


def test_camera_worker_fails_loudly_when_a_camera_is_lost(studio):
    """A lost camera is an error (non-zero exit: restarted), not a clean finish (exit 0: never restarted)."""
    with pytest.raises(WorkerError, match="cam0.*device lost"):
        run_camera_worker(studio.session(listen=True), studio.keys, {"cam0": _UnpluggedCamera()}, mode="live",
                          stop=studio.stop)


def test_lossless_camera_worker_fails_when_no_consumer(studio):
    with pytest.raises(WorkerError, match="not reachable within 0.3 s"):
        run_camera_worker(studio.session(listen=True), studio.keys, {"cam0": _UnpluggedCamera()},
                          mode="lossless", stop=studio.stop, startup_timeout_s=0.3)


def test_segment_worker_fails_loudly_when_its_segmenter_crashes(rng, studio):
    def broken(frame, image):
        raise RuntimeError("segmenter bug")

    keys = studio.keys
    sender = studio.session(listen=True)
    pub = declare_publisher(sender, keys.frame("cam0"))
    demand = declare_publisher(sender, keys.demand("track"))
    frame = FrameMessage.from_image("cam0", 1, 0, rng.integers(0, 256, (30, 40, 3), dtype=np.uint8))

    stop, done = threading.Event(), threading.Event()

    def send():  # live: the frame is segmented only once the tracker demands it
        if not wait_until_matched([pub, demand], timeout_s=10.0):
            return stop.set()
        deadline = time.monotonic() + 20.0
        while not done.is_set() and time.monotonic() < deadline:  # again until it lands: a demand that
            pub.put(frame.to_bytes())  # overtakes its frame is dropped as not held
            time.sleep(0.05)
            demand.put(DemandMessage("track", 1).to_bytes())
            done.wait(0.5)
        stop.set()  # never hang: the worker then returns and pytest.raises fails

    threading.Thread(target=send, daemon=True).start()
    try:
        with pytest.raises(WorkerError, match="cam0.*RuntimeError: segmenter bug"):
            run_segment_worker(studio.session(), keys, {"cam0": broken}, mode="live", stop=stop)
    finally:
        done.set()


def test_worker_command_missing_camera_is_one_clear_error(tmp_path, capsys):
    from service.commands import worker

    cfg = tmp_path / "studio.toml"
    cfg.write_text(f"""[studio]\nname = "t"\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n
[[camera]]\nname = "cam0"\nhost = "h"\nbackend = "opencv"\nsource = "/dev/video-none"\n""")
    rc = worker.main(["camera", "--config", str(cfg), "--host", "h"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert err[-1].startswith("contourcap worker camera: camera 'cam0' (/dev/video-none)")
    assert not any("Traceback" in line for line in err)


def test_free_running_cameras_share_frame_ids_across_processes_and_restarts(tmp_path):
    """Without a trigger box, frame ids come from the wall clock: two cameras opened at different
    times (or one reopened) give the same id to frames taken within half a period of each other."""
    import cv2

    from service.config import load_config
    from service.workers.runtime import build_sources, free_run_frame_ids

    assert [free_run_frame_ids(25.0)(t) for t in (0, 19_999_999, 20_000_000, 40_000_000, 59_999_999)] == [0, 0, 1, 1, 1]
    ids = free_run_frame_ids(100.0)  # 10 ms ticks (the config's trigger fps)
    video = tmp_path / "cam.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (40, 30))
    for _ in range(2000):  # a file reads faster than the clock ticks: frames of a tick already used are skipped
        writer.write(np.zeros((30, 40, 3), np.uint8))
    writer.release()
    cfg_path = tmp_path / "studio.toml"
    cfg_path.write_text('[studio]\nname = "t"\n[trigger]\nfps = 100.0\n' + "".join(
        f'[[camera]]\nname = "{c}"\nhost = "h"\nbackend = "opencv"\nsource = "{video}"\n' for c in ("a", "b")))
    cfg = load_config(cfg_path)
    first = build_sources(cfg, ("a",), mode="live")["a"]
    second = None
    try:
        early = first.read()  # camera a has delivered a frame before camera b's process starts
        second = build_sources(cfg, ("b",), mode="live")["b"]
        fa, fb = first.read(), second.read()
        assert early.frame_id < fa.frame_id and fa.frame_id == ids(fa.timestamp_ns)
        # b's first frame is numbered by the clock like a's, not 0: taken after a's first, a higher id
        assert early.frame_id < fb.frame_id == ids(fb.timestamp_ns) <= ids(time.time_ns())
        assert abs(fa.frame_id - fb.frame_id) <= 1 + (abs(fa.timestamp_ns - fb.timestamp_ns) // 10_000_000)
    finally:
        first.close()
        if second is not None:
            second.close()


def test_preloaded_replay_cameras_decode_side_by_side_and_read_as_streamed(tmp_path, rng):
    """A live replay's cameras decoded into memory in threads read exactly what reading replays read; a
    camera whose video is missing fails the whole set with its name."""
    from service.config import load_config
    from service.demo import write_studio
    from service.workers.sources import build_sources
    from tests.support.sessions import make_session

    cams = ("cam0", "cam1", "cam2")
    session, expected = make_session(tmp_path / "s", rng, cams=cams, n_frames=6)
    cfg = load_config(write_studio(tmp_path / "s", tmp_path / "out", port=free_port(), delivery="live"))
    sources = build_sources(cfg, cams, mode="live", paced=True, preload=True)
    try:
        for name in cams:
            got = [sources[name].read() for _ in range(6)]
            assert [f.frame_id for f in got] == list(range(6))
            for f in got:
                np.testing.assert_array_equal(f.image, expected[name][f.frame_id])
    finally:
        for src in sources.values():
            src.close()
    (tmp_path / "s" / "cam1.avi").unlink()
    with pytest.raises(Exception, match="cam1"):
        build_sources(cfg, cams, mode="live", paced=True, preload=True)
