"""Hostile file input (issue 16): every bad input is one line and exit 2, and nothing is lost.

Each test is a failure seen on the tree before the fix, re-run as a regression test: the error is one
line on stderr (no traceback), the exit code is 2, and an existing output is byte-for-byte unchanged.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from service.cli import main
from tests.support.sessions import make_session

EXISTING = b'{"frame": 0, "ok": false, "reason": "an earlier take"}\n' * 3


def one_line_error(capsys, rc: int, *words: str) -> str:
    """The command's stderr, checked: exit 2, no traceback, its last line says ``words``."""
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err, err
    last = err.strip().splitlines()[-1]
    assert "error" in last.lower() or "contourcap" in last, last
    for w in words:
        assert w in last, (w, last)
    return last


@pytest.fixture
def session_dir(tmp_path, rng):
    make_session(tmp_path / "s", rng, cams=("cam0", "cam1"), n_frames=6)
    return tmp_path / "s"


def test_track_random_bytes_video_keeps_existing_poses(session_dir, tmp_path, capsys):
    (session_dir / "cam1.avi").write_bytes(np.random.default_rng(1).bytes(5000))
    out = tmp_path / "poses.jsonl"
    out.write_bytes(EXISTING)
    rc = main(["track", str(session_dir), "--out", str(out)])
    one_line_error(capsys, rc, "cam1")
    assert out.read_bytes() == EXISTING
    assert not (tmp_path / "poses.jsonl.partial").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["poses.jsonl", "s"]


def test_track_bad_range_keeps_existing_poses(session_dir, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    out.write_bytes(EXISTING)
    rc = main(["track", str(session_dir), "--out", str(out), "--frames", "5:2"])
    one_line_error(capsys, rc, "--frames")
    assert out.read_bytes() == EXISTING


def test_debug_shows_the_traceback(session_dir, tmp_path, capsys):
    (session_dir / "cam1.avi").write_bytes(b"\x00" * 100)
    rc = main(["--debug", "track", str(session_dir), "--out", str(tmp_path / "p.jsonl")])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" in err


@pytest.mark.parametrize("argv", [["export", "{poses}", "--csv", "{tmp}/x.csv", "--fps", "0"],
                                  ["synth", "bundled:scaled_131_03", "{tmp}/o", "--fps", "nan"]])
def test_fps_zero_refused(argv, tmp_path, capsys):
    poses = tmp_path / "p.jsonl"
    poses.write_bytes(EXISTING)
    with pytest.raises(SystemExit) as exc:
        main([a.format(poses=poses, tmp=tmp_path) for a in argv])
    assert exc.value.code == 2
    assert "--fps" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["run", "view", "echo"])
def test_studio_toml_of_random_bytes(command, tmp_path, capsys):
    bad = tmp_path / "studio.toml"
    bad.write_bytes(b"\xff\xfe" + np.random.default_rng(2).bytes(300))
    rc = main([command, "--config", str(bad)])
    one_line_error(capsys, rc, str(bad))


def test_demo_unknown_motion_before_anything_is_made(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rc = main(["demo", "--motion", "nope", "--cache", str(tmp_path / "cache")])
    one_line_error(capsys, rc, "nope")
    assert os.listdir(tmp_path) == []


def test_demo_default_output_is_not_the_working_directory():
    from service.commands.demo import add_args, options_from_args
    import argparse

    p = argparse.ArgumentParser()
    add_args(p)
    opts = options_from_args(p.parse_args(["--cache", "/some/cache"]))
    assert opts.out_dir is None  # run_demo puts it under the cache: <cache>/last-demo


@pytest.mark.parametrize("escape", ["../../../etc/passwd", "/etc/passwd", "a/../../outside.avi"])
def test_session_path_escaping_is_refused_by_name(escape, session_dir, capsys):
    toml = session_dir / "session.toml"
    toml.write_text(toml.read_text().replace('video = "cam1.avi"', f'video = "{escape}"'))
    rc = main(["replay", str(session_dir)])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert "leaves the session folder" in err and escape in err and "cam1" in err


def test_session_symlink_inside_the_folder_is_followed(session_dir, tmp_path):
    from capture.session import load_session

    outside = tmp_path / "media.avi"
    (session_dir / "cam1.avi").rename(outside)
    (session_dir / "cam1.avi").symlink_to(outside)
    assert load_session(session_dir).camera("cam1").video == session_dir / "cam1.avi"


def _pose(frame: int, ok: bool = True) -> bytes:
    import json

    rec = {"frame": frame, "timestamp_ns": frame * 40_000_000, "ok": ok,
           "joints": {"pelvis": [0.0, 0.0, 1.0], "head": [0.0, 0.0, 1.7]}}
    if not ok:
        rec = {"frame": frame, "timestamp_ns": frame * 40_000_000, "ok": False, "reason": "lost"}
    return json.dumps(rec).encode()


def test_export_skips_and_reports_a_cut_last_line(tmp_path, capsys):
    poses = tmp_path / "p.jsonl"
    whole = b"\n".join(_pose(k) for k in range(5)) + b"\n"
    poses.write_bytes(whole + _pose(5)[:17])  # a power cut in the middle of the last record
    rc = main(["export", str(poses), "--csv", str(tmp_path / "p.csv")])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "skipped 1 line" in err and "line 6" in err and "cut short" in err
    assert len((tmp_path / "p.csv").read_text().splitlines()) == 1 + 5


def test_export_malformed_line_refused_unless_skip_bad(tmp_path, capsys):
    poses = tmp_path / "p.jsonl"
    poses.write_bytes(_pose(0) + b"\n\x1b[2J{not json\n" + _pose(1) + b"\n")
    out = tmp_path / "p.csv"
    out.write_bytes(EXISTING)
    rc = main(["export", str(poses), "--csv", str(out)])
    last = one_line_error(capsys, rc, f"{poses}:2", "--skip-bad")
    assert "\x1b" not in last
    assert out.read_bytes() == EXISTING
    rc = main(["export", str(poses), "--csv", str(out), "--skip-bad"])
    err = capsys.readouterr().err
    assert rc == 0 and "skipped 1 line" in err and "\x1b" not in err
    assert len(out.read_text().splitlines()) == 1 + 2


def test_export_all_lost_names_the_input(tmp_path, capsys):
    poses = tmp_path / "lost.jsonl"
    poses.write_bytes(b"\n".join(_pose(k, ok=False) for k in range(3)) + b"\n")
    bvh = tmp_path / "out.bvh"
    bvh.write_bytes(EXISTING)
    rc = main(["export", str(poses), "--bvh", str(bvh)])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    assert str(poses) in err.strip().splitlines()[-1] and "lost" in err
    assert bvh.read_bytes() == EXISTING


def test_export_without_session_says_the_height_it_assumes(capsys):
    import argparse

    from service.commands.export import model_for_export

    args = argparse.Namespace(model=None, height_m=None, session=None)
    assert model_for_export(args, []).name == "knossow40"
    assert "1.75 m" in capsys.readouterr().err
    model_for_export(argparse.Namespace(model=None, height_m=1.6, session=None), [])
    assert capsys.readouterr().err == ""


def test_echo_escapes_received_strings():
    from service.commands.echo import format_pose
    from service.wire.records import PoseRecord

    rec = PoseRecord.from_dict({"frame": 3, "timestamp_ns": 0, "ok": False,
                                "reason": "\x1b]52;c;ZXZpbA==\x07\x1b[2J\u202eevil"})
    line = format_pose(rec)
    assert "\x1b" not in line and "\x07" not in line and "\u202e" not in line
    assert "\\x1b]52" in line and "\\u202e" in line


def test_calibration_size_must_match_the_videos(session_dir, tmp_path, capsys):
    from capture.calibration import load_calibration, save_calibration
    from capture.camera import Camera

    cams = load_calibration(session_dir / "calibration.toml")
    wrong = [Camera.look_at(c.name, (3, 0, 1.5), (0, 0, 1), size=(128, 96)) if c.name == "cam1" else c for c in cams]
    save_calibration(session_dir / "calibration.toml", wrong)
    out = tmp_path / "poses.jsonl"
    out.write_bytes(EXISTING)
    rc = main(["track", str(session_dir), "--out", str(out)])
    one_line_error(capsys, rc, "cam1", "64x48", "128x96")
    assert out.read_bytes() == EXISTING


def test_frames_past_the_end_say_the_length(session_dir, tmp_path, capsys):
    rc = main(["track", str(session_dir), "--out", str(tmp_path / "p.jsonl"), "--frames", "100:200"])
    one_line_error(capsys, rc, "100:200", "6 frames")
    assert not (tmp_path / "p.jsonl").exists()


def test_a_cut_camera_is_named_with_frames_read_and_expected(tmp_path, rng, capsys):
    from tests.support.sessions import make_images, write_video

    make_session(tmp_path / "s", rng, cams=("cam0", "cam1", "cam2"), n_frames=8)
    write_video(tmp_path / "s" / "cam2.avi", make_images(rng, 3))  # the recording of cam2 stopped early
    out = tmp_path / "poses.jsonl"
    out.write_bytes(EXISTING)
    rc = main(["track", str(tmp_path / "s"), "--out", str(out)])
    one_line_error(capsys, rc, "cam2", "3 frames", "longest camera 8", "--allow-missing-cameras")
    from capture.media import MissingFramesError, StreamCheck, check_media
    from capture.session import load_session

    session = load_session(tmp_path / "s")
    media = check_media(session, session.camera_names)
    check = StreamCheck(media)
    for fid in range(3):
        check.see(fid, ("cam0", "cam1", "cam2"))
    with pytest.raises(MissingFramesError, match=r"cam2.*3 frames read of 8 expected.*--allow-missing-cameras"):
        check.see(3, ("cam0", "cam1"))
    lenient = StreamCheck(media, allow_missing=True)
    for fid in range(8):
        assert lenient.see(fid, ("cam0", "cam1", "cam2") if fid < 3 else ("cam0", "cam1")) == (
            [] if fid < 3 else ["cam2"])
    assert lenient.report() == ["camera cam2: 5 frame(s) missing, 3 frames read of 8 expected"]
    assert out.read_bytes() == EXISTING


def test_declared_drops_are_not_missing_frames(tmp_path, rng):
    from capture.media import StreamCheck, check_media
    from capture.session import load_session

    make_session(tmp_path / "s", rng, cams=("cam0", "cam1"), n_frames=6, csv=True, drops={"cam1": [2, 3]})
    session = load_session(tmp_path / "s")
    check = StreamCheck(check_media(session, session.camera_names))
    for fid in range(6):
        check.see(fid, ("cam0",) if fid in (2, 3) else ("cam0", "cam1"))
    assert check.missing == {}


def test_replay_reports_a_cut_camera_as_dropped(tmp_path, rng, capsys):
    import json

    from tests.support.sessions import make_images, write_video

    make_session(tmp_path / "s", rng, cams=("cam0", "cam1"), n_frames=8)
    write_video(tmp_path / "s" / "cam1.avi", make_images(rng, 3))
    assert main(["replay", str(tmp_path / "s"), "--json"]) == 0
    cams = json.loads(capsys.readouterr().out)["cameras"]
    assert cams["cam0"]["dropped"] == 0 and cams["cam1"]["frames"] == 3
    assert cams["cam1"]["dropped"] == 5 and cams["cam1"]["missing_at_end"] == 5


def test_review_interrupted_keeps_an_existing_video(session_dir, tmp_path):
    from capture.session import load_session
    from service.review import write_review

    out = tmp_path / "review.mp4"
    out.write_bytes(EXISTING)
    records = [{"frame": k, "timestamp_ns": 0, "ok": False, "reason": "x"} for k in range(6)]

    def interrupt(done, total, label):
        if done >= 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_review(load_session(session_dir), records, video=out, progress=interrupt)
    assert out.read_bytes() == EXISTING
    assert sorted(os.listdir(tmp_path)) == ["review.mp4", "s"]  # no temporary file left
    write_review(load_session(session_dir), records, video=out)
    assert out.read_bytes() != EXISTING and out.stat().st_size > 1000
