"""One contract suite for every camera source backend (STYLE.md item 9).

Each backend fixture returns ``make(tmp_path, rng, n) -> (source, expected)``
with ``expected`` the list of ``(frame_id, image)`` the source must deliver,
and ``missing(tmp_path) -> source`` whose open must fail.
"""

from __future__ import annotations

import numpy as np
import pytest

from capture.replay import ReplaySource
from capture.session import load_session, write_session_toml
from capture.sources import EndOfStream, Frame, OpenError, Source, SourceError
from tests.support.sessions import make_images, make_session, write_video


def _replay(kind):
    def make(tmp_path, rng, n):
        session, expected = make_session(tmp_path, rng, kind=kind, n_frames=n, csv=True, drops={"cam0": [1]})
        return ReplaySource(session, "cam0"), sorted(expected["cam0"].items())

    def missing(tmp_path):
        (tmp_path / "x.avi").write_bytes(b"")
        write_session_toml(tmp_path, name="m", fps=25, cameras=[{"name": "cam0", "video": "x.avi"}])
        session = load_session(tmp_path, require_calibration=False)
        (tmp_path / "x.avi").unlink()
        return ReplaySource(session, "cam0")

    return make, missing


def _replay_segments():
    from capture.recorder import Recorder

    def make(tmp_path, rng, n):
        images = make_images(rng, n)
        with Recorder(tmp_path / "rec", name="seg", fps=25, cameras=["cam0"], codec="ffv1", segment_s=0.08) as rec:
            for k, img in enumerate(images):
                rec.write(Frame("cam0", 3 * k, 1000 * k, img))  # every third pulse stored
        session = load_session(tmp_path / "rec", require_calibration=False)
        assert len(session.camera("cam0").video_files) == -(-n // 2)  # 2-frame segments
        return ReplaySource(session, "cam0"), [(3 * k, img) for k, img in enumerate(images)]

    _, missing = _replay("video")
    return make, missing


def _opencv():
    from capture.opencv_source import OpenCVSource

    ticks = iter(range(10**6, 10**9, 1000))

    def make(tmp_path, rng, n):
        images = make_images(rng, n)
        path = write_video(tmp_path / "file.avi", images)
        return OpenCVSource(str(path), name="cam0", clock=lambda: next(ticks)), list(enumerate(images))

    def missing(tmp_path):
        return OpenCVSource(str(tmp_path / "x.avi"), name="cam0")

    return make, missing


BACKENDS = {
    "replay-video": lambda: _replay("video"),
    "replay-images": lambda: _replay("images"),
    "replay-segments": _replay_segments,
    "opencv-file": _opencv,
}


@pytest.fixture(params=sorted(BACKENDS))
def backend(request):
    return BACKENDS[request.param]()


def test_is_a_source(backend, tmp_path, rng):
    make, _ = backend
    src, _ = make(tmp_path, rng, 3)
    assert isinstance(src, Source) and src.name == "cam0"


def test_delivers_every_frame_exactly_then_end(backend, tmp_path, rng):
    make, _ = backend
    src, expected = make(tmp_path, rng, 6)
    with src:
        frames = [src.read() for _ in expected]
        with pytest.raises(EndOfStream):
            src.read()
        with pytest.raises(EndOfStream):
            src.read()
    assert [f.frame_id for f in frames] == [fid for fid, _ in expected]
    for frame, (_, image) in zip(frames, expected):
        assert isinstance(frame, Frame) and frame.camera == "cam0"
        assert frame.image.dtype == np.uint8 and frame.image.shape == (48, 64, 3)
        assert np.array_equal(frame.image, image)
    assert all(np.diff([f.frame_id for f in frames]) > 0)
    assert all(np.diff([f.timestamp_ns for f in frames]) >= 0)
    assert all(isinstance(f.timestamp_ns, int) and isinstance(f.frame_id, int) for f in frames)


def test_read_when_not_open(backend, tmp_path, rng):
    make, _ = backend
    src, _ = make(tmp_path, rng, 2)
    with pytest.raises(SourceError, match="not open"):
        src.read()
    with src:
        src.read()
    with pytest.raises(SourceError, match="not open"):
        src.read()


def test_open_failure_named(backend, tmp_path):
    _, missing = backend
    src = missing(tmp_path)
    with pytest.raises(OpenError, match="x.avi"):
        with src:
            pass


def test_reopen_starts_again(backend, tmp_path, rng):
    make, _ = backend
    src, expected = make(tmp_path, rng, 3)
    with src:
        src.read()
    with src:
        assert src.read().frame_id == expected[0][0]
