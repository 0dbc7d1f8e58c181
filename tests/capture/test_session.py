"""Session directory: load/validate/write, timestamps CSV, image patterns."""

from __future__ import annotations

import pytest

from capture.session import (
    SessionError,
    image_frame_ids,
    load_session,
    read_timestamps,
    write_session_toml,
)
from tests.support.sessions import make_session


def test_round_trip_fields(tmp_path, rng):
    session, _ = make_session(tmp_path, rng, csv=True, background=True)
    assert session.name == "synthetic" and session.fps == 25.0 and session.height_m == 1.7
    cam = session.camera("cam0")
    assert cam.video == tmp_path / "cam0.avi" and cam.images is None
    assert cam.timestamps == tmp_path / "cam0.csv" and cam.background == tmp_path / "background" / "cam0.avi"
    assert [c.name for c in session.calibration] == ["cam0", "cam1"]
    assert session.camera_model("cam1").size == (64, 48)
    # load through the toml path too
    assert load_session(tmp_path / "session.toml").camera_names == session.camera_names


def test_segment_lengths_and_image_cameras(tmp_path, rng):
    make_session(tmp_path, rng, kind="images", n_frames=4, drops={"cam1": [2]})
    write_session_toml(
        tmp_path,
        name="s",
        fps=50,
        cameras=[{"name": "cam0", "images": "cam0/%06d.png"}, {"name": "cam1", "images": "cam1/%06d.png"}],
        segment_lengths={"upper_arm": 0.3},
    )
    session = load_session(tmp_path)
    assert session.segment_lengths == {"upper_arm": 0.3} and session.height_m is None
    assert session.camera("cam0").images == str(tmp_path / "cam0" / "%06d.png")
    assert image_frame_ids(session.camera("cam1").images).tolist() == [0, 1, 3]


def test_calibration_order_follows_session(tmp_path, rng):
    make_session(tmp_path, rng, n_frames=2)
    write_session_toml(
        tmp_path, name="s", fps=25, cameras=[{"name": "cam1", "video": "cam1.avi"}, {"name": "cam0", "video": "cam0.avi"}]
    )
    session = load_session(tmp_path)
    assert [c.name for c in session.calibration] == ["cam1", "cam0"]


@pytest.mark.parametrize(
    "edit, needle",
    [
        (lambda t: t.replace('video = "cam1.avi"', 'video = "nope.avi"'), "nope.avi"),
        (lambda t: t.replace('name = "cam1"', 'name = "cam0"'), "unique"),
        (lambda t: t.replace("fps = 25.0", "fps = -1"), "'fps'"),
        (lambda t: t.replace('video = "cam1.avi"', 'video = "cam1.avi"\nimages = "x/%d.png"'), "exactly one"),
        (lambda t: t.replace('name = "cam1"', 'name = "cam9"'), "cam9"),
        (lambda t: t.replace('name = "cam1"', 'name = "cam1"\ncolour = 1'), "colour"),
        (lambda t: t.replace("[session]", "[sesion]"), "[session]"),
        (lambda t: t.replace("height_m = 1.7", "height_m = 17"), "height_m"),
        (lambda t: t + "\n[[camera]\n", "invalid TOML"),
        (lambda t: t.replace('video = "cam1.avi"', 'video = "cam%x.avi"'), "camera 'cam1': image pattern"),
    ],
)
def test_bad_session_named_error(tmp_path, rng, edit, needle):
    make_session(tmp_path, rng, n_frames=2)
    path = tmp_path / "session.toml"
    path.write_text(edit(path.read_text()))
    with pytest.raises(SessionError) as info:
        load_session(tmp_path)
    assert needle in str(info.value)
    assert "session.toml" in str(info.value) or "calibration.toml" in str(info.value)


def test_missing_calibration(tmp_path, rng):
    make_session(tmp_path, rng, n_frames=2)
    (tmp_path / "calibration.toml").unlink()
    with pytest.raises(SessionError, match="calibration.toml"):
        load_session(tmp_path)
    session = load_session(tmp_path, require_calibration=False)
    assert session.calibration == ()
    with pytest.raises(SessionError, match="no calibration.toml"):
        session.camera_model("cam0")


def test_missing_session_and_unknown_camera(tmp_path, rng):
    with pytest.raises(SessionError, match="session file not found"):
        load_session(tmp_path)
    session, _ = make_session(tmp_path, rng, n_frames=2)
    with pytest.raises(SessionError, match="cam7"):
        session.camera("cam7")


def test_timestamps_csv(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("frame_id,timestamp_ns\n0,100\n2,300\n\n5,600\n")
    ids, ts = read_timestamps(p)
    assert ids.tolist() == [0, 2, 5] and ts.tolist() == [100, 300, 600]
    for text, needle in [
        ("id,ts\n0,1\n", "header"),
        ("frame_id,timestamp_ns\n0,1\n0,2\n", "strictly increasing"),
        ("frame_id,timestamp_ns\n0,5\n1,2\n", "non-decreasing"),
        ("frame_id,timestamp_ns\n0,1\nx,2\n", "c.csv:3"),
        ("frame_id,timestamp_ns\n0,1,2\n", "c.csv:2"),
    ]:
        p.write_text(text)
        with pytest.raises(SessionError, match=needle):
            read_timestamps(p)


def test_image_pattern_validation(tmp_path):
    with pytest.raises(SessionError, match="exactly one"):
        image_frame_ids(str(tmp_path / "frame.png"))
    assert image_frame_ids(str(tmp_path / "absent" / "%04d.png")).size == 0
    (tmp_path / "f0007.png").write_bytes(b"")
    (tmp_path / "f12.png").write_bytes(b"")
    (tmp_path / "g3.png").write_bytes(b"")
    assert image_frame_ids(str(tmp_path / "f%04d.png")).tolist() == [7, 12]


def test_write_session_toml_rejects_bad_cameras(tmp_path):
    with pytest.raises(SessionError, match="exactly one"):
        write_session_toml(tmp_path, name="s", fps=25, cameras=[{"name": "a"}])
    with pytest.raises(SessionError, match="unique"):
        write_session_toml(tmp_path, name="s", fps=25, cameras=[{"name": "a", "video": "a"}, {"name": "a", "video": "b"}])
    with pytest.raises(SessionError, match="fps"):
        write_session_toml(tmp_path, name="s", fps=0, cameras=[{"name": "a", "video": "a"}])
    assert not (tmp_path / "session.toml").exists()
