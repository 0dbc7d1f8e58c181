"""OpenCV backend specifics: trigger-mapped frame ids on an injected clock, live-device open errors."""

from __future__ import annotations

import pytest

from capture.opencv_source import OpenCVSource
from capture.sources import OpenError
from capture.trigger import SoftwareTrigger
from tests.support.sessions import make_images, write_video

MS = 1_000_000


def test_frame_ids_from_trigger_time_grid(tmp_path, rng):
    path = write_video(tmp_path / "v.avi", make_images(rng, 6))
    now = [1_000 * MS]
    trig = SoftwareTrigger(clock=lambda: now[0], fps=50)
    trig.start()
    arrivals = iter([5, 25, 31, 85, 106, 127])  # ms after the first pulse; 31 shares pulse 1 with 25

    def clock():
        now[0] = 1_000 * MS + next(arrivals) * MS
        return now[0]

    with OpenCVSource(str(path), name="c", clock=clock, frame_id_at=trig.frame_id_at) as src:
        frames = [src.read() for _ in range(4)]
        assert src.skipped == 1
    # 5 -> 0, 25 -> 1, 31 -> 1 again: skipped (no lasting offset), 85 -> 4 (pulses 2, 3 dropped), 106 -> 5
    assert [f.frame_id for f in frames] == [0, 1, 4, 5]
    assert [f.timestamp_ns for f in frames] == [1_000 * MS + t * MS for t in (5, 25, 85, 106)]


def test_missing_device_named():
    src = OpenCVSource("/dev/video-contourcap-absent", name="cam7")
    with pytest.raises(OpenError, match="cam7.*/dev/video-contourcap-absent"):
        src.open()
    assert not src.is_file


def test_constructor_validation():
    with pytest.raises(ValueError, match="name"):
        OpenCVSource(0, name="")
    with pytest.raises(ValueError, match="device"):
        OpenCVSource(1.5, name="c")


def test_size_other_than_asked_is_refused(tmp_path, rng):
    images = make_images(rng, 2)
    h, w = images[0].shape[:2]
    path = write_video(tmp_path / "v.avi", images)
    with OpenCVSource(str(path), name="c", width=w, height=h) as src:  # the size it delivers: fine
        assert src.read().image.shape[:2] == (h, w)
    with pytest.raises(OpenError, match=rf"'c'.*asked for {w * 2}x{h} but it delivers {w}x{h}"):
        OpenCVSource(str(path), name="c", width=w * 2, height=h).open()
