"""Replay backend specifics: timestamps/drops, frame ranges, loop, pacing, backgrounds, frame sets."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from capture.replay import ReplaySource, iter_frame_sets, parse_frame_range, read_frames
from capture.session import SessionError, load_session, write_session_toml
from capture.sources import EndOfStream, OpenError, SourceTimeout
from tests.support.sessions import make_images, make_session, write_video


class FakeClock:
    """Injected clock: ``sleep`` advances it; records every sleep."""

    def __init__(self, start_ns: int = 5_000_000_000):
        self.now = start_ns
        self.sleeps: list[float] = []

    def clock(self) -> int:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += int(round(seconds * 1e9))


@pytest.mark.parametrize("kind", ["video", "images"])
def test_csv_drops_reproduced(tmp_path, rng, kind):
    session, expected = make_session(tmp_path, rng, kind=kind, n_frames=8, csv=True, drops={"cam1": [2, 3, 6]})
    frames = list(read_frames(session, "cam1"))
    assert [f.frame_id for f in frames] == [0, 1, 4, 5, 7]
    assert [f.timestamp_ns for f in frames] == [1_000_000_007 + 40_000_000 * k for k in (0, 1, 4, 5, 7)]
    for f in frames:
        assert np.array_equal(f.image, expected["cam1"][f.frame_id])


def test_images_without_csv_use_file_numbers(tmp_path, rng):
    session, expected = make_session(tmp_path, rng, kind="images", n_frames=5, drops={"cam0": [1]})
    frames = list(read_frames(session, "cam0"))
    assert [f.frame_id for f in frames] == [0, 2, 3, 4]
    assert [f.timestamp_ns for f in frames] == [0, 80_000_000, 120_000_000, 160_000_000]


@pytest.mark.parametrize("kind", ["video", "images"])
def test_frame_range(tmp_path, rng, kind):
    session, expected = make_session(tmp_path, rng, kind=kind, n_frames=10, csv=True, drops={"cam0": [5]})
    frames = list(read_frames(session, "cam0", frames=range(3, 9, 2)))
    assert [f.frame_id for f in frames] == [3, 7]
    assert all(np.array_equal(f.image, expected["cam0"][f.frame_id]) for f in frames)
    with pytest.raises(ValueError, match="frames"):
        ReplaySource(session, "cam0", frames=range(9, 3, -1))


def test_loop_keeps_ids_and_time_increasing(tmp_path, rng):
    session, expected = make_session(tmp_path, rng, n_frames=3)
    with ReplaySource(session, "cam0", loop=True) as src:
        frames = [src.read() for _ in range(7)]
    assert [f.frame_id for f in frames] == list(range(7))
    assert [f.timestamp_ns for f in frames] == [40_000_000 * k for k in range(7)]
    assert np.array_equal(frames[4].image, expected["cam0"][1])


def test_realtime_pacing_on_injected_clock(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, n_frames=4, csv=True, drops={"cam0": [2]})
    clk = FakeClock()
    with ReplaySource(session, "cam0", pacing="realtime", clock=clk.clock, sleep=clk.sleep) as src:
        first = src.read()
        t_first = clk.now
        clk.now += 10_000_000  # the reader spent 10 ms on frame 0
        src.read()
        src.read()  # frame 3 after the 2-frame gap
        assert clk.now - t_first == 120_000_000
        clk.now += 500_000_000  # reader fell far behind: next read must not sleep
        n_sleeps = len(clk.sleeps)
        with pytest.raises(EndOfStream):
            src.read()
    assert first.frame_id == 0
    assert clk.sleeps[:2] == pytest.approx([0.030, 0.080])
    assert len(clk.sleeps) == n_sleeps


def test_step_pacing(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, n_frames=5)
    with ReplaySource(session, "cam0", pacing="step", step_timeout_s=0.05) as src:
        src.step(2)
        assert [src.read().frame_id for _ in range(2)] == [0, 1]
        with pytest.raises(SourceTimeout, match="cam0"):
            src.read()
        timer = threading.Timer(0.02, src.step)
        timer.start()
        src.step_timeout_s = 5.0
        assert src.read().frame_id == 2  # released by the other thread
        timer.join()


def test_background_replay(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, n_frames=2, background=True)
    frames = list(read_frames(session, "cam1", background=True))
    assert [f.frame_id for f in frames] == [0, 1, 2]
    bare, _ = make_session(tmp_path / "bare", rng, n_frames=2)
    with pytest.raises(OpenError, match="no background"):
        ReplaySource(bare, "cam0", background=True).open()


def test_frame_sets_offline_with_drops(tmp_path, rng):
    session, expected = make_session(
        tmp_path, rng, cams=("a", "b", "c"), n_frames=6, csv=True, drops={"a": [1], "b": [1, 4], "c": [5]}
    )
    sets = list(iter_frame_sets(session))
    assert [fid for fid, _ in sets] == [0, 1, 2, 3, 4, 5]
    members = {fid: sorted(group) for fid, group in sets}
    assert members[1] == ["c"] and members[4] == ["a", "c"] and members[5] == ["a", "b"] and members[0] == ["a", "b", "c"]
    for fid, group in sets:
        for cam, frame in group.items():
            assert frame.frame_id == fid and np.array_equal(frame.image, expected[cam][fid])
    sub = list(iter_frame_sets(session, cameras=["c"], frames=range(2, 4)))
    assert [(fid, list(g)) for fid, g in sub] == [(2, ["c"]), (3, ["c"])]


def test_video_cut_shorter_than_csv_ends_cleanly(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, n_frames=4, csv=True)
    csv = tmp_path / "cam0.csv"
    csv.write_text(csv.read_text() + "4,1160000007\n5,1200000007\n")
    assert [f.frame_id for f in read_frames(load_session(tmp_path), "cam0")] == [0, 1, 2, 3]


def test_corrupt_media_named(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, n_frames=2)
    (tmp_path / "cam0.avi").write_bytes(b"not a video at all" * 10)
    with pytest.raises(OpenError, match="cam0.avi"):
        ReplaySource(session, "cam0").open()
    with pytest.raises(SessionError, match="cam5"):
        ReplaySource(session, "cam5")
    (tmp_path / "cam1.csv").write_text("frame_id;timestamp_ns\n")
    bad = tmp_path / "session.toml"
    bad.write_text(bad.read_text().replace('video = "cam1.avi"', 'video = "cam1.avi"\ntimestamps = "cam1.csv"'))
    with pytest.raises(OpenError, match="cam1.csv"):
        ReplaySource(load_session(tmp_path), "cam1").open()


def test_real_uu_studio_video(shared_data, tmp_path):
    video = shared_data / "uu_studio" / "cam1" / "video.avi"
    if not video.is_file():
        pytest.skip(f"{video} absent")
    (tmp_path / "cam1.avi").symlink_to(video)  # session paths stay inside the folder; a symlink may leave it
    (tmp_path / "session.toml").write_text(
        '[session]\nname = "uu"\nfps = 50.0\n\n[[camera]]\nname = "cam1"\nvideo = "cam1.avi"\n'
    )
    session = load_session(tmp_path, require_calibration=False)
    frames = list(read_frames(session, "cam1", frames=range(0, 5)))
    assert [f.frame_id for f in frames] == [0, 1, 2, 3, 4]
    assert frames[0].image.shape == (486, 644, 3) and frames[0].image.dtype == np.uint8
    assert frames[4].timestamp_ns == 80_000_000
    assert 20 < float(frames[0].image.mean()) < 235  # a real, lit room, not a blank frame


def test_video_segments_read_back_to_back(tmp_path, rng):
    images = make_images(rng, 7)
    (tmp_path / "cam0").mkdir()
    write_video(tmp_path / "cam0" / "000000.avi", images[:4])
    write_video(tmp_path / "cam0" / "000004.avi", images[4:])
    (tmp_path / "cam0" / "000007.avi").write_bytes(b"cut short")  # last segment of a crashed recording
    write_session_toml(tmp_path, name="seg", fps=25, cameras=[{"name": "cam0", "video": "cam0/%06d.avi"}])
    session = load_session(tmp_path, require_calibration=False)
    assert [p.name for p in session.camera("cam0").video_files] == ["000000.avi", "000004.avi", "000007.avi"]
    frames = list(read_frames(session, "cam0"))
    assert [f.frame_id for f in frames] == list(range(7))
    assert all(np.array_equal(f.image, img) for f, img in zip(frames, images))
    assert [f.frame_id for f in read_frames(session, "cam0", frames=range(3, 6))] == [3, 4, 5]
    (tmp_path / "cam0" / "000004.avi").write_bytes(b"broken in the middle")
    with pytest.raises(OpenError, match="000004.avi"):
        list(read_frames(load_session(tmp_path, require_calibration=False), "cam0"))


def test_parse_frame_range():
    assert parse_frame_range(None) is None and parse_frame_range("") is None
    assert parse_frame_range("3:9") == range(3, 9)
    assert parse_frame_range(":4") == range(0, 4) and parse_frame_range("5:").start == 5
    for bad in ("3", "a:b", "9:3", "-1:2", "1:2:3"):
        with pytest.raises(ValueError, match="--frames"):
            parse_frame_range(bad)


@pytest.mark.parametrize("kind", ["video", "images"])
def test_preloaded_replay_serves_what_a_looping_replay_reads(tmp_path, rng, kind):
    """``preload=True`` decodes at open and then reads exactly what a reading replay reads (loop or not)."""
    session, _ = make_session(tmp_path, rng, cams=("cam1",), n_frames=5, kind=kind, drops={"cam1": [2]}, csv=True)
    for loop in (True, False):
        with ReplaySource(session, "cam1", loop=loop, preload=True) as pre, \
                ReplaySource(session, "cam1", loop=loop) as ref:
            for _ in range(12 if loop else 4):
                a, b = pre.read(), ref.read()
                assert (a.camera, a.frame_id, a.timestamp_ns) == (b.camera, b.frame_id, b.timestamp_ns)
                assert np.array_equal(a.image, b.image)
            if not loop:
                with pytest.raises(EndOfStream):
                    pre.read()
