"""The wire trusts nothing (issue 16): far-future ids, floods and oversized frames from a hostile peer
cannot redirect the live tracker's demands, push out real demands, or grow a worker's memory."""

from __future__ import annotations

import numpy as np
import pytest

from service.flow.demand import DemandPlanner, FrameRing
from service.flow.window import FrameIdWindow, RateLimit
from service.wire.messages import FrameMessage

FAR = 10**12


def _frame(camera, fid, rng, shape=(6, 8, 3)):
    return FrameMessage.from_image(camera, fid, fid * 40_000_000, rng.integers(0, 256, shape, dtype=np.uint8)).to_bytes()


def test_far_future_have_does_not_change_the_next_demand():
    p = DemandPlanner(("a", "b"))
    t = 0.0
    for k in range(10):  # a running studio at 30 fps
        t = k / 30
        p.have("a", tuple(range(100 + k - 7, 101 + k)), t)
        p.have("b", tuple(range(100 + k - 7, 101 + k)), t)
    p.have("a", (FAR,), t)  # a hostile peer announcing frame 10^12 for both cameras
    p.have("b", (FAR, FAR - 1), t)
    assert p.rejected >= 3
    fid = p.next_demand(t + 0.01)
    assert fid == 109  # the newest real frame both hold, not 10^12
    p.released(fid)
    p.have("a", (110,), t + 0.04)
    p.have("b", (110,), t + 0.04)
    assert p.next_demand(t + 0.05) == 110  # and the studio goes on


def test_far_future_first_notice_is_overruled_by_the_cameras_own_numbering():
    p = DemandPlanner(("a",))
    p.have("a", (FAR,), 0.0)  # the attacker spoke first
    p.have("a", (5, 6), 0.01)  # the real camera: a renumbering, accepted
    assert p.next_demand(0.02) == 6
    p.have("a", (FAR,), 0.03)
    assert p.rejected == 1


def test_window_bounds_and_restart_holdoff():
    w = FrameIdWindow(rate_hz=30, ahead_s=1.0, behind=10, slack=5, restart_holdoff_s=1.0)
    assert w.accept(100, 0.0)
    assert w.upper(0.0) == 135 and not w.accept(136, 0.0) and w.accept(135, 0.0)
    assert w.upper(2.0) == 135 + 30 * 3 + 5  # the trigger ran on for 2 s (+ 1 s ahead + slack)
    assert w.accept(0, 0.1) and w.restarts == 1  # renumbered
    assert not w.accept(5000, 0.2)  # far future after the restart too
    assert w.accept(3, 0.2)
    assert w.restarts == 1 and w.rejected == 2
    assert not w.accept(-1, 0.3)


def test_have_flood_is_rate_limited():
    p = DemandPlanner(("a",))
    accepted = sum(p.have("a", (k,), 0.0) for k in range(1000))
    assert accepted <= 64 and p.limited >= 936  # one instant: the burst only
    r = RateLimit(10.0, burst=2)
    assert [r.allow(0.0) for _ in range(3)] == [True, True, False]
    assert r.allow(0.1) and not r.allow(0.1)


def test_far_future_demands_cannot_push_out_a_real_one(rng):
    t = [0.0]
    ring = FrameRing("cam0", size=4, max_demands=4, clock=lambda: t[0])
    for fid in range(10, 14):
        assert ring.put(_frame(("cam0"), fid, rng), None) == fid
    assert ring.demand(13, 0.0)
    for _ in range(100):
        assert not ring.demand(FAR, 0.0)
    assert ring.rejected == 100
    missed, got = ring.next_demanded(0.0, wait_s=0.5)
    assert missed == [] and got[0] == 13


def test_far_future_frame_refused_and_memory_bounded(rng):
    t = [0.0]
    big = _frame("cam0", 1, rng, shape=(200, 300, 3))  # 180 kB
    ring = FrameRing("cam0", size=8, max_bytes=3 * len(big), clock=lambda: t[0])
    assert ring.put(_frame("cam0", 0, rng), None) == 0
    assert ring.put(_frame("cam0", FAR, rng), None) is None and ring.rejected == 1
    for fid in range(1, 40):
        t[0] = fid / 30
        ring.put(_frame("cam0", fid, rng, shape=(200, 300, 3)), None)
        assert ring._bytes <= ring.max_bytes and len(ring) <= 3
    assert ring.take_news()[-1] == 39
    rejected = ring.rejected
    assert ring.put(_frame("cam0", 40, rng, shape=(500, 500, 3)), None) is None  # larger than the budget
    assert ring.rejected == rejected + 1 and ring.take_news() is None


@pytest.mark.parametrize("reason", ["\x1b[2J\x1b]0;pwned\x07", "ok\u202etxt.exe", "a\rb\x00c\x9b"])
def test_printable_escapes_everything_a_terminal_acts_on(reason):
    from service.text import printable

    out = printable(reason)
    assert all(c.isprintable() for c in out), repr(out)
    assert printable("x" * 500, limit=10) == "x" * 9 + "…"


def test_echo_stats_line_shows_rejected_and_evicted_escaped():
    from service.commands.echo import format_stats

    line = format_stats({"received": 10, "rejected": 3, "evicted": 1},
                        {"track": {"rejected": 41.0, "fps": 9.0, "bad": 0.0},
                         "segment-h1": {"evicted": 2.0, "rejected": 7.0}})
    assert "received 10, rejected 3, evicted 1" in line
    assert "track: rejected 41" in line and "fps" not in line
    assert "segment-h1: evicted 2, rejected 7" in line


def test_live_studio_keeps_tracking_through_far_future_haves_and_demands(tmp_path, rng, studio):
    """A hostile peer publishes have notices and demands for frame 10^12 (and junk) on every camera's
    keys while a 2-second session is replayed live: the tracker still fits the real frames to the end,
    never a far-future one, and the workers count what they refused."""
    import threading

    from service.wire.records import DemandMessage, HaveMessage
    from tests.support.workers import CAMS, fitter, make_session, segmenter, wait_for

    session = make_session(tmp_path / "s", rng, n_frames=50)  # 2 s at 25 fps
    stop = threading.Event()
    sent = [0]

    def attack():
        while not studio.sessions and not stop.is_set():  # the track worker's listening session first
            stop.wait(0.01)
        attacker = studio.session()
        while not stop.is_set() and sent[0] < 20_000:
            for cam in CAMS:
                attacker.put(studio.keys.have(cam), HaveMessage(cam, (FAR, FAR - 1)).to_bytes())
                attacker.put(studio.keys.frame(cam), b"CCAP" + bytes(30))
            attacker.put(studio.keys.demand("track"), DemandMessage("track", FAR).to_bytes())
            sent[0] += 2 * len(CAMS) + 1
            stop.wait(0.005)

    thread = threading.Thread(target=attack, daemon=True)
    thread.start()
    try:
        poses, _ = studio.run_live(session, fitter, segmenter)
        assert wait_for(lambda: poses and poses[-1].frame == 49, 5.0), [p.frame for p in poses]
    finally:
        stop.set()
        thread.join(5)
    frames = [p.frame for p in poses]
    assert max(frames) < 50 and frames == sorted(set(frames)) and len(frames) >= 10
    assert sent[0] > 100


class _Sample:
    def __init__(self, key, data):
        self.key_expr, self.attachment = key, None
        self.payload = type("P", (), {"to_bytes": lambda _self: data})()


class _Session:
    def declare_subscriber(self, key, callback):
        return type("S", (), {"undeclare": lambda _self: None})()


def test_have_flood_on_one_key_cannot_push_out_another_cameras_notice():
    from service.wire.bus import Inbox
    from service.wire.records import HaveMessage

    inbox = Inbox(_Session(), "contourcap/x/cam/*/have", HaveMessage.from_bytes, depth=8, latest_per_key=True)
    inbox._on_sample(_Sample("contourcap/x/cam/cam0/have", HaveMessage("cam0", (100, 101)).to_bytes()))
    for k in range(1000):  # a flood on cam3's key
        inbox._on_sample(_Sample("contourcap/x/cam/cam3/have", HaveMessage("cam3", (FAR + k,)).to_bytes()))
    got = {r.key.split("/")[3]: r.message for r in inbox.drain()}
    assert got["cam0"].frame_ids == (100, 101) and got["cam3"].frame_ids == (FAR + 999,)
    assert inbox.dropped == 0 and len(inbox) == 0
    plain = Inbox(_Session(), "k/*", HaveMessage.from_bytes, depth=8)
    plain._on_sample(_Sample("k/cam0", HaveMessage("cam0", (1,)).to_bytes()))
    for k in range(20):
        plain._on_sample(_Sample("k/cam3", HaveMessage("cam3", (k,)).to_bytes()))
    assert all(r.message.camera == "cam3" for r in plain.drain())  # what the flood did before


def test_a_cameras_first_notice_cannot_jump_ahead_of_the_others():
    p = DemandPlanner(("a", "b"))
    p.have("a", (100, 101), 0.0)
    p.have("b", (FAR,), 0.01)  # b's first notice is the attacker's
    assert p.rejected == 1
    p.have("b", (100, 101), 0.02)
    assert p.next_demand(0.03) == 101
    p.have("b", (FAR,), 0.04)  # and later ones meet b's own window
    assert p.rejected == 2
