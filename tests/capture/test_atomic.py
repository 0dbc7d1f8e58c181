"""Atomic outputs (issue 16): a failing writer never truncates an existing file, a kill keeps every
finished pose record, and no temporary file is left behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from capture.atomic import JsonlWriter, atomic_open, atomic_path, write_text_atomic
from capture.calibration import save_calibration
from capture.camera import Camera

OLD = b"old contents\n" * 100


def test_failed_write_leaves_file_and_folder_as_they_were(tmp_path):
    path = tmp_path / "out.txt"
    path.write_bytes(OLD)
    with pytest.raises(RuntimeError):
        with atomic_open(path, "wb") as fh:
            fh.write(b"half")
            raise RuntimeError("writer failed")
    assert path.read_bytes() == OLD
    assert os.listdir(tmp_path) == ["out.txt"]


def test_success_replaces_and_keeps_mode(tmp_path):
    path = tmp_path / "out.txt"
    path.write_bytes(OLD)
    os.chmod(path, 0o640)
    write_text_atomic(path, "new\n")
    assert path.read_text() == "new\n"
    assert (os.stat(path).st_mode & 0o777) == 0o640
    assert os.listdir(tmp_path) == ["out.txt"]


def test_atomic_path_keeps_the_suffix_and_needs_a_file(tmp_path):
    path = tmp_path / "v.avi"
    with pytest.raises(OSError):
        with atomic_path(path) as tmp:
            assert tmp.suffix == ".avi" and tmp.parent == tmp_path
            tmp.unlink()  # a writer that produced nothing
    assert not path.exists() and os.listdir(tmp_path) == []


def test_calibration_save_failure_keeps_the_old_file(tmp_path):
    path = tmp_path / "calibration.toml"
    path.write_bytes(OLD)
    cam = Camera.look_at("cam0", (3, 0, 1.5), (0, 0, 1), size=(64, 48))
    with pytest.raises(ValueError):
        save_calibration(path, [cam, cam])  # duplicate names: refused
    assert path.read_bytes() == OLD


def test_jsonl_writer_commit_abandon(tmp_path):
    out = tmp_path / "poses.jsonl"
    out.write_bytes(OLD)
    w = JsonlWriter(out)
    w.write(b'{"frame": 0}')
    assert w.abandon() == w.partial  # an existing file is never replaced by an incomplete run
    assert out.read_bytes() == OLD and w.partial.read_bytes() == b'{"frame": 0}\n'
    w = JsonlWriter(out)
    assert w.abandon() is None and not w.partial.exists()  # nothing finished: nothing left
    new = tmp_path / "new.jsonl"
    w = JsonlWriter(new)
    w.write(b'{"frame": 0}')
    assert w.abandon() == new and new.read_bytes() == b'{"frame": 0}\n'  # no old file: the frames are the output
    with JsonlWriter(out) as w:
        w.write(b'{"frame": 1}')
    assert out.read_bytes() == b'{"frame": 1}\n' and not w.partial.exists()


def test_sigkill_keeps_every_finished_record(tmp_path):
    out = tmp_path / "poses.jsonl"
    out.write_bytes(OLD)
    code = textwrap.dedent(f"""
        import sys, time
        from capture.atomic import JsonlWriter
        w = JsonlWriter({str(out)!r})
        for k in range(5):
            w.write(b'{{"frame": %d}}' % k)
        print("ready", flush=True)
        time.sleep(60)
    """)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, env=env)
    try:
        assert p.stdout.readline().strip() == b"ready"
        p.send_signal(signal.SIGKILL)
        p.wait(10)
    finally:
        p.kill()
    assert out.read_bytes() == OLD
    lines = (tmp_path / "poses.jsonl.partial").read_bytes().splitlines()
    assert lines == [b'{"frame": %d}' % k for k in range(5)]


def test_new_file_gets_the_umask_mode(tmp_path):
    old = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "new.txt", "x")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "new.txt").st_mode & 0o777) == 0o640
