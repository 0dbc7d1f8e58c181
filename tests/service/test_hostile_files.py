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
