"""`contourcap record` and `contourcap replay` through the real CLI dispatcher."""

from __future__ import annotations

import json

import numpy as np

from capture.replay import read_frames
from capture.session import load_session
from service.cli import main
from tests.support.sessions import make_session
from tests.support.trigger import FakeBox, FakeTriggerBackend


def write_config(path, session_dir, cams=("cam0", "cam1")):
    lines = ['[studio]', 'name = "lab"', f'session = "{session_dir}"', ""]
    for c in cams:
        lines += ["[[camera]]", f'name = "{c}"', 'host = "h1"' if c == "cam0" else 'host = "h2"', 'backend = "replay"', ""]
    path.write_text("\n".join(lines))
    return path


def test_record_cli_round_trip(tmp_path, rng, capsys):
    src, _ = make_session(tmp_path / "src", rng, n_frames=6, csv=True, drops={"cam0": [2]})
    cfg = write_config(tmp_path / "studio.toml", src.root)
    rc = main(["record", "--config", str(cfg), str(tmp_path / "out"), "--codec", "ffv1", "--pacing", "fast"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "cam0: 5 frames, 1 dropped" in out and "cam1: 6 frames, 0 dropped" in out
    rec = load_session(tmp_path / "out")
    for name in ("cam0", "cam1"):
        a, b = list(read_frames(src, name)), list(read_frames(rec, name))
        assert [(f.frame_id, f.timestamp_ns) for f in a] == [(f.frame_id, f.timestamp_ns) for f in b]
        assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
    # host filter + frame limit
    rc = main(["record", "--config", str(cfg), str(tmp_path / "out2"), "--host", "h2", "--frames", "2", "--pacing", "fast"])
    assert rc == 0 and load_session(tmp_path / "out2").camera_names == ("cam1",)
    capsys.readouterr()
    # refusing to overwrite is an error exit, named
    assert main(["record", "--config", str(cfg), str(tmp_path / "out"), "--pacing", "fast"]) == 2
    assert "never overwritten" in capsys.readouterr().err
    # options that would record nothing (or spin) are refused before the output exists
    for option, value in (("--frames", "0"), ("--duration-s", "-1"), ("--segment-s", "0"), ("--resync-s", "0")):
        assert main(["record", "--config", str(cfg), str(tmp_path / "out3"), option, value]) == 2
        assert f"record: error: {option}: expected" in capsys.readouterr().err
        assert not (tmp_path / "out3").exists()


def test_replay_cli_reports_fps(tmp_path, rng, capsys):
    src, _ = make_session(tmp_path / "src", rng, n_frames=6, csv=True, drops={"cam1": [1, 2]})
    assert main(["replay", str(src.root), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["cameras"]["cam1"]["frames"] == 4 and report["cameras"]["cam1"]["dropped"] == 2
    assert report["cameras"]["cam0"]["fps"] > 0
    assert main(["replay", str(src.root), "--cameras", "cam9"]) == 2
    assert "cam9" in capsys.readouterr().err
    assert main(["replay", str(src.root), "--cameras", " , "]) == 2
    assert "--cameras: no camera names" in capsys.readouterr().err


def test_record_trigger_resync_thread_stops_on_unplug():
    import errno
    import threading

    from capture.trigger import start_trigger_box

    box = FakeBox()
    stop, errors = threading.Event(), []
    tb = start_trigger_box(50.0, stop=stop, resync_s=0.01, on_lost=lambda exc: errors.append(str(exc)),
                           backend=FakeTriggerBackend(box))
    last_id, last_host_ns = tb.refresh()
    assert tb.frame_id_at(last_host_ns) == last_id
    box.unplugged_errno = errno.ENODEV
    assert stop.wait(5.0)  # the resync thread saw the unplug and stopped the recording
    assert errors and "disconnected" in errors[0]


def test_record_trigger_start_failure_releases_the_device():
    import threading

    import pytest

    from capture.trigger import TriggerError, start_trigger_box

    class Backend(FakeTriggerBackend):
        closed = 0

        def close_device(self, dev_handle):
            Backend.closed += 1

    box = FakeBox()
    box.stall.add(0x03)  # the box refuses START
    with pytest.raises(TriggerError):
        start_trigger_box(50.0, stop=threading.Event(), backend=Backend(box))
    assert Backend.closed == 1
