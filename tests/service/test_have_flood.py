"""A flood of implausible have notices on a camera's own key (bench/hostile.py sends 1 000 a second,
frame 10^12) neither displaces that camera's real notices nor wakes the track worker's loop: they
are dropped on receipt, before they take the key's place in the latest-per-key inbox."""

from __future__ import annotations

import threading
import time

import pytest

from service.flow.demand import DemandPlanner
from service.wire.bus import Inbox, Keys, ZenohSettings, free_port, open_session
from service.wire.records import HaveMessage

FAR = 10**12


def test_planner_plausible_is_what_have_would_take():
    p = DemandPlanner(("cam0", "cam1"))
    assert p.plausible("cam0", (FAR,), 0.0)  # no window yet: the planner itself decides
    p.have("cam0", (100, 101), 0.0)
    assert p.plausible("cam0", (102,), 0.04) and p.plausible("cam0", (), 0.04)
    assert not p.plausible("cam0", (FAR, FAR - 1), 0.04) and not p.plausible("camX", (102,), 0.04)
    assert p.plausible("cam0", (FAR, 103), 0.04)  # one plausible id is enough
    rejected = p.rejected
    p.plausible("cam0", (FAR,), 0.05)
    assert p.rejected == rejected  # read-only


@pytest.fixture
def pair():
    port = free_port()
    a = open_session(ZenohSettings.loopback(port, listen=True))
    b = open_session(ZenohSettings.loopback(port, listen=False))
    yield a, b
    b.close()
    a.close()


def test_implausible_flood_does_not_displace_real_notices(pair):
    a, b = pair
    keys = Keys("flood")
    planner = DemandPlanner(("cam0",))
    planner.have("cam0", (500,), time.monotonic())
    cv = threading.Condition()
    inbox = Inbox(b, keys.have("*"), HaveMessage.from_bytes, depth=8, cv=cv, latest_per_key=True,
                  keep=lambda key, msg: (keys.camera_of(key) == msg.camera
                                         and planner.plausible(msg.camera, msg.frame_ids, time.monotonic())))
    time.sleep(0.3)  # the subscription reaches the other session
    a.put(keys.have("cam0"), HaveMessage("cam0", (501,)).to_bytes())  # the camera's real notice ...
    for _ in range(500):  # ... then a flood on its key: far future, and another camera's on this key
        a.put(keys.have("cam0"), HaveMessage("cam0", (FAR,)).to_bytes())
        a.put(keys.have("cam0"), HaveMessage("cam1", (502,)).to_bytes())
    deadline = time.monotonic() + 5.0
    while inbox.received + inbox.refused < 1001 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert inbox.received == 1 and inbox.refused == 1000
    got = inbox.drain()
    assert [(r.key, r.message.frame_ids) for r in got] == [(keys.have("cam0"), (501,))]
    inbox.close()


def test_far_future_demands_do_not_push_out_the_real_demands_regions(pair, rng):
    """The segment worker keeps the regions of interest of the newest 16 demands: a flood of
    demands for frame 10^12 (which no camera takes) pushed the real ones out, and demanded frames
    were segmented whole."""
    from service.wire.records import DemandMessage
    from service.workers.segment import SegmentWorker
    from tests.support.plugins import segmenter

    a, b = pair
    keys = Keys("rois")
    worker = SegmentWorker(b, keys, {"cam0": segmenter}, mode="live", stop=threading.Event())
    try:
        from service.wire.messages import FrameMessage

        image = rng.integers(0, 256, (6, 8, 3), dtype="uint8")
        worker.rings["cam0"].put(FrameMessage.from_image("cam0", 7, 0, image).to_bytes(), None)
        time.sleep(0.3)
        a.put(keys.demand("track"), DemandMessage("track", 7, {"cam0": (0, 0, 4, 4)}).to_bytes())
        for _ in range(100):
            a.put(keys.demand("track"), DemandMessage("track", FAR).to_bytes())
        deadline = time.monotonic() + 5.0
        while worker.rings["cam0"].rejected < 100 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert worker.rings["cam0"].rejected == 100
        assert worker.demand_rois == {7: {"cam0": (0, 0, 4, 4)}}
    finally:
        worker.close()
