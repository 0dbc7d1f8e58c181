"""The camera worker's trigger wiring: the USB box (pyusb through the fake backend of test_trigger)
numbers the frames of an OpenCV source; with a trigger, one camera process owns all the host's cameras."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from service.config import load_config
from service.workers.runtime import build_sources, needs_trigger, start_trigger
from service.flow.supervisor import plan_host

from tests.support.trigger import FakeBox, FakeTriggerBackend, host_clock  # noqa: E402  (pyusb fake backend)


def _studio(tmp_path, rng, *, trigger):
    import cv2

    video = tmp_path / "cam0.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (32, 24))
    for _ in range(5):
        writer.write(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8))
    writer.release()
    path = tmp_path / "studio.toml"
    path.write_text(f'[studio]\nname = "trig"\n\n[trigger]\nbackend = "{trigger}"\nfps = 30.0\n\n'
                    + "".join(f'[[camera]]\nname = "{c}"\nhost = "h"\nbackend = "opencv"\nsource = "{video}"\n\n'
                              for c in ("cam0", "cam1")))
    return load_config(path)


def test_trigger_box_numbers_opencv_frames(tmp_path, rng):
    cfg = _studio(tmp_path, rng, trigger="usb")
    assert needs_trigger(cfg, ("cam0",))
    box_state = FakeBox()
    stop = threading.Event()
    box = start_trigger(cfg, stop, backend=FakeTriggerBackend(box_state), clock=host_clock(box_state))
    try:
        assert box.period_us == round(1e6 / 30.0)
        box_state.now_us += 10 * box.period_us  # ten pulses later
        box.refresh()
        clock_ns = host_clock(box_state)()
        expected = box.frame_id_at(clock_ns)
        sources = build_sources(cfg, ("cam0",), mode="live", frame_id_at=lambda ts: box.frame_id_at(clock_ns))
        frame = sources["cam0"].read()
        sources["cam0"].close()
        assert frame.frame_id == expected >= 10
    finally:
        stop.set()
        box.close()
    assert [s.name for s in plan_host(cfg, "studio.toml", "h")] == ["camera", "segment", "track"]


def test_without_trigger_one_process_per_camera(tmp_path, rng):
    cfg = _studio(tmp_path, rng, trigger="none")
    assert not needs_trigger(cfg, ("cam0", "cam1"))
    names = [s.name for s in plan_host(cfg, "studio.toml", "h", camera_processes="per-camera")]
    assert names == ["camera-cam0", "camera-cam1", "segment", "track"]
    # a small host (or asked for): one camera process for all the host's cameras
    one = plan_host(cfg, "studio.toml", "h", camera_processes="one")
    assert [s.name for s in one] == ["camera", "segment", "track"]
    assert "cam0,cam1" in one[0].argv


def test_missing_trigger_box_is_a_config_error(tmp_path, rng):
    from service.config import ConfigError

    cfg = _studio(tmp_path, rng, trigger="usb")
    with pytest.raises(ConfigError, match="trigger"):
        start_trigger(cfg, threading.Event(), backend=FakeTriggerBackend())
