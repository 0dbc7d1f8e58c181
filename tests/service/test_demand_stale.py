"""Genuine have notices are never refused: a frame the tracker went past does not stay in a segment
worker's ring (and in every notice), and a stale id beside the newest ones does not drag a camera's
frame-id window back (which refused the camera's real frames as "far future" once it ran behind)."""

from __future__ import annotations

import numpy as np

from service.flow.demand import DemandPlanner, FrameRing
from service.flow.window import FrameIdWindow
from service.wire.messages import FrameMessage

WALL_IDS = 53_000_000_000  # free-running cameras number frames by the wall clock (frame_ids.py): ids ~ 5e10


def _frame(fid: int) -> bytes:
    return FrameMessage.from_image("cam0", fid, 0, np.zeros((4, 6, 3), np.uint8)).to_bytes()


def test_ring_drops_frames_older_than_a_demand():
    t = [0.0]
    ring = FrameRing("cam0", size=8, clock=lambda: t[0])
    for fid in (10, 11, 12):
        ring.put(_frame(fid), None)
    assert ring.demand(12, 0.0)
    missed, got = ring.next_demanded(0.0, wait_s=0.5)
    assert missed == [] and got[0] == 12
    assert len(ring) == 0 and ring.skipped == 2 and ring._bytes == 0  # 10 and 11 will never be demanded
    for fid in (13, 15):
        ring.put(_frame(fid), None)
    ring.demand(14, 0.0)  # never arrived, 15 has: missed, and 13 goes with it
    missed, got = ring.next_demanded(0.0, wait_s=0.5)
    assert missed == [14] and got is None and ring.take_news() == (15,)


def test_stale_id_in_a_notice_does_not_move_the_window_back():
    w = FrameIdWindow(rate_hz=30, ahead_s=1.0, behind=10, slack=5, restart_holdoff_s=1.0)
    assert w.filter((WALL_IDS + 100,), 0.0) == (WALL_IDS + 100,)
    for k in range(1, 60):  # beside the newest ids, an old one the notice still names
        assert w.filter((WALL_IDS, WALL_IDS + 100 + k), 2.0 + k / 30) == (WALL_IDS + 100 + k,)
    assert w.restarts == 0 and w.rejected == 0 and w.stale == 59
    assert w.filter((3, 4), 5.0) == (3, 4) and w.restarts == 1  # a notice that went back whole: renumbered


def test_camera_keeping_up_stays_live_with_nothing_refused():
    """A segment worker's ring and the tracker's planner as the live pipeline drives them, 90 s at
    30 fps with wall-clock ids, a tracker that takes every frame: two frames arrive before the first
    demand (the older is never demanded).  The camera is live throughout and no notice is refused."""
    ring = FrameRing("cam0", size=8, clock=lambda: now)
    planner = DemandPlanner(("cam0",))
    demanded, now = [], 0.0
    for k in range(90 * 30):
        now = k / 30
        ring.put(_frame(WALL_IDS + k), None)
        if k == 0:
            continue  # the tracker is not up yet: frame 0 waits in the ring
        assert planner.have("cam0", ring.take_news(), now), k
        fid = planner.next_demand(now)
        if fid is not None:
            ring.demand(fid, now)
            _, got = ring.next_demanded(now, wait_s=0.5)
            demanded.append(got[0])
            planner.released(got[0])
        assert planner.live(now) == ("cam0",), k
    assert planner.rejected == 0
    assert len(demanded) >= 90 * 30 - 2 and demanded == sorted(set(demanded))


def test_a_forged_low_id_cannot_blind_a_running_camera():
    """A peer announcing frame 0 (or sending a frame numbered 0) on a running camera's key: taken for
    a renumbering, it moved the camera's reference back and its real ids (wall-clock, ~5e10) were
    refused as far ahead for good.  A confirmed numbering that is still running is not replaced."""
    planner = DemandPlanner(("cam0",))
    ring = FrameRing("cam0", size=8, clock=lambda: now)
    for k in range(300):
        now = k / 30
        assert planner.have("cam0", (WALL_IDS + k,), now)
        assert ring.put(_frame(WALL_IDS + k), None) == WALL_IDS + k
        if k % 30 == 29:  # once a second, forged
            assert not planner.have("cam0", (0,), now + 0.001)
            assert ring.put(_frame(0), None) is None
    assert planner.live(now) == ("cam0",) and planner.rejected == 10 and ring.rejected == 10
    assert planner.next_demand(now) == WALL_IDS + 299


def test_a_stopped_numbering_is_replaced_and_a_first_forged_id_overruled():
    w = FrameIdWindow(rate_hz=30, ahead_s=1.0, behind=10, slack=5, restart_holdoff_s=1.0)
    for k in range(5):
        assert w.accept(500 + k, k / 30)
    assert not w.accept(0, 0.5)  # the numbering runs on: not a renumbering
    assert not w.accept(0, 1.1) and w.accept(0, 1.2)  # stopped for 1 s (last id at 0.13 s): renumbered
    assert w.restarts == 1 and w.accept(1, 1.3)
    v = FrameIdWindow(rate_hz=30, ahead_s=1.0, behind=10, slack=5, restart_holdoff_s=1.0)
    assert v.accept(10**12, 0.0)  # a hostile first id, never confirmed
    assert v.accept(7, 0.01) and v.accept(8, 0.04) and not v.accept(10**12, 0.05)


def test_a_hostile_first_frame_does_not_stay_in_the_ring():
    """A peer's frame numbered 10^12 reached the ring before the camera's first: the camera's own
    numbering overrules it and it is dropped, so a demanded frame that has not arrived yet is waited
    for (a far-ahead frame held made every such demand 'missed' at once: sets without that camera)."""
    t = [0.0]
    ring = FrameRing("cam0", size=8, clock=lambda: t[0])
    assert ring.put(_frame(10**12), None) == 10**12
    for k in range(3):
        t[0] = 0.1 + k / 30
        assert ring.put(_frame(k), None) == k
    assert ring.take_news() == (0, 1, 2) and ring.skipped == 1
    assert ring.demand(3, t[0])
    assert ring.next_demanded(t[0], wait_s=0.5) == ([], None)  # not arrived yet: waited for
    ring.put(_frame(3), None)
    assert ring.next_demanded(t[0], wait_s=0.5)[1][0] == 3
