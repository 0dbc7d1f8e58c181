"""`contourcap worker track --max-frames N` as a process: its last pose, credit and 'finished' status
reach a reader, and it keeps its zenoh session open LINGER_S after them (a session closed right after a
put loses what a slow reader has not read yet)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from pathlib import Path

from capture.replay import iter_frame_sets
from service.wire.bus import Inbox, Keys, ZenohSettings, declare_publisher, free_port, open_session, wait_until_matched
from service.commands.worker import LINGER_S
from service.demo import STUDIO, write_studio
from service.wire.messages import FrameMessage
from service.wire.records import CreditMessage, PoseRecord, StatusMessage

from tests.support.workers import CAMS, make_session, segmenter

ROOT = Path(__file__).resolve().parents[2]


def test_track_worker_max_frames_lingers_after_its_last_messages(tmp_path, rng):
    session = make_session(tmp_path / "s", rng, n_frames=2)
    port = free_port()
    cfg = write_studio(tmp_path / "s", tmp_path / "out", port=port, delivery="lossless")
    hub = open_session(ZenohSettings.loopback(port, listen=True))
    keys = Keys(STUDIO)
    arrived: dict[str, float] = {}
    lock = threading.Lock()

    def stamp(decode, name):
        def f(data):
            msg = decode(data)
            with lock:
                arrived[f"{name}{getattr(msg, 'frame', getattr(msg, 'frame_id', ''))}"] = time.monotonic()
            return msg
        return f

    poses = Inbox(hub, keys.pose, stamp(PoseRecord.from_bytes, "pose"), mode="lossless", depth=16)
    credits = Inbox(hub, keys.credit("*"), stamp(CreditMessage.from_bytes, "credit"), mode="lossless", depth=16)
    status = Inbox(hub, keys.status("track"), StatusMessage.from_bytes, mode="lossless", depth=64)
    errf = (tmp_path / "stderr.txt").open("w")
    proc = subprocess.Popen([sys.executable, "-m", "service.commands.worker", "track", "--config", str(cfg),
                             "--hub", f"tcp/127.0.0.1:{port}", "--max-frames", "2",
                             "--plugin", "tests.support.plugins:fitter_factory"], cwd=ROOT,
                            stderr=errf)
    try:
        pubs = {c: declare_publisher(hub, keys.chamfer(c), mode="lossless") for c in CAMS}
        assert wait_until_matched(list(pubs.values()), timeout_s=60.0), "the track worker never subscribed"
        for fid, group in iter_frame_sets(session):
            for c, f in group.items():
                pubs[c].put(segmenter(FrameMessage.from_image(c, fid, f.timestamp_ns, f.image), f.image).to_bytes())
        rc = proc.wait(60.0)
        exited = time.monotonic()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        errf.close()
        hub.close()
    err = (tmp_path / "stderr.txt").read_text()
    assert rc == 0, err
    assert [p.message.frame for p in poses.drain()] == [0, 1], err
    assert sorted(c.message.frame_id for c in credits.drain()) == [0, 1], err
    assert [s.message.state for s in status.drain()][-1] == "finished", err
    last = max(arrived["pose1"], arrived["credit1"])
    # the worker exits at least LINGER_S after its last put, less the put's delivery time (loopback: ms;
    # without the linger it was 0.06-0.16 s on a 2-core box)
    assert exited - last > 0.6 * LINGER_S, (exited - last, err)
