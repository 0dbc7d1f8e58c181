"""The capture part of studio.toml: one reader for `contourcap record` and the service."""

from __future__ import annotations

import pytest

from capture.studio import DEFAULT_FPS, parse_studio_capture, read_studio_toml
from tests.support.sessions import make_session

OPENCV = [{"name": "usb", "backend": "opencv", "source": "0"}]


def test_fps_default_is_the_replay_sessions_else_30(tmp_path, rng):
    make_session(tmp_path / "sess", rng, cams=("cam0",), n_frames=3, fps=25.0)
    replay = {"studio": {"session": "sess"}, "camera": [{"name": "cam0"}]}
    assert parse_studio_capture(replay, base=tmp_path).fps == 25.0
    assert parse_studio_capture({"camera": OPENCV}).fps == DEFAULT_FPS == 30.0
    explicit = {**replay, "trigger": {"fps": 50, "backend": "usb", "port": "x"}}
    cap = parse_studio_capture(explicit, base=tmp_path)
    assert (cap.fps, cap.trigger, dict(cap.trigger_options)) == (50.0, "usb", {"port": "x"})
    assert cap.session == tmp_path / "sess" and cap.calibration is None and cap.name == "studio"


@pytest.mark.parametrize("data, key", [
    ({"camera": OPENCV, "trigger": {"fps": 0}}, "trigger.fps"),
    ({"camera": OPENCV, "trigger": {"fps": True}}, "trigger.fps"),
    ({"camera": OPENCV, "trigger": {"backend": "gige"}}, "trigger.backend"),
    ({"camera": [{"name": "cam0"}]}, "studio.session"),
    ({"camera": OPENCV, "studio": {"session": 3}}, "studio.session"),
    ({"camera": OPENCV, "studio": {"name": ""}}, "studio.name"),
    ({"camera": OPENCV + OPENCV}, r"camera\[1\]\.name"),
    ({"camera": [{"name": "cam0", "backend": "opencv"}]}, r"camera\[0\]\.source"),
    ({"camera": OPENCV, "studio": []}, r"\[studio\]"),
])
def test_errors_name_the_key(data, key):
    with pytest.raises(ValueError, match=key):
        parse_studio_capture(data, where="studio.toml")


def test_missing_session_names_its_file(tmp_path):
    with pytest.raises(ValueError, match="session.toml"):
        parse_studio_capture({"studio": {"session": "gone"}, "camera": [{"name": "c"}]}, base=tmp_path)


def test_read_errors_name_the_file(tmp_path):
    with pytest.raises(ValueError, match="cannot read"):
        read_studio_toml(tmp_path / "missing.toml")
    (tmp_path / "bad.toml").write_text("[studio\n")
    with pytest.raises(ValueError, match="bad.toml: not valid TOML"):
        read_studio_toml(tmp_path / "bad.toml")
