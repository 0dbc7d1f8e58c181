"""Supervisor with real worker processes on loopback zenoh: a killed camera worker is restarted and
rejoins; meanwhile the tracker keeps publishing with one camera fewer.  Back-off unit test."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from service.wire.bus import Inbox, Keys, ZenohSettings, free_port, open_session
from service.config import load_config
from service.wire.records import PoseRecord
from service.flow.supervisor import SMALL_HOST_CPUS, ProcessSpec, Supervisor, plan_host

REPO = Path(__file__).resolve().parents[2]
CAMS = ("cam0", "cam1", "cam2")
PLUGINS = "tests.support.plugins"


def make_studio(tmp_path, rng, *, n_frames, delivery, port, studio="sup"):
    import cv2

    from capture.calibration import save_calibration
    from capture.camera import Camera
    from capture.session import write_session_toml

    root = tmp_path / "session"
    cams = []
    for i, name in enumerate(CAMS):
        (root / name).mkdir(parents=True)
        for k in range(n_frames):
            cv2.imwrite(str(root / name / f"{k:06d}.png"), rng.integers(0, 256, (30, 40, 3), dtype=np.uint8))
        cams.append({"name": name, "images": f"{name}/%06d.png"})
    write_session_toml(root, name="t", fps=25.0, cameras=cams)
    save_calibration(root / "calibration.toml", [
        Camera.look_at(n, eye=(3 * np.cos(a), 3 * np.sin(a), 1.5), target=(0, 0, 1), size=(40, 30))
        for n, a in zip(CAMS, (0.0, 2.0, 4.0))])
    cam_tables = "".join(f'[[camera]]\nname = "{c}"\nhost = "h1"\nbackend = "replay"\nencoding = "png"\n\n'
                         for c in CAMS)
    path = tmp_path / "studio.toml"
    path.write_text(f'[studio]\nname = "{studio}"\ndelivery = "{delivery}"\nsession = "session"\n\n'
                    f'[zenoh]\nlisten = ["tcp/127.0.0.1:{port}"]\n\n'
                    f'[tracker]\nhost = "h1"\nset_timeout_ms = 60\n\n' + cam_tables)
    return path


def test_killed_camera_restarts_and_rejoins(tmp_path, rng):
    port = free_port()
    path = make_studio(tmp_path, rng, n_frames=150, delivery="live", port=port)
    cfg = load_config(path)
    hub = open_session(ZenohSettings.loopback(port, listen=True))
    inbox = Inbox(hub, Keys("sup").pose, PoseRecord.from_bytes, mode="lossless", depth=10_000)
    specs = plan_host(cfg, str(path), "h1", hub=f"tcp/127.0.0.1:{port}", epoch_ns=time.time_ns() + int(2.5e9),
                      segment_plugin=f"{PLUGINS}:segmenter_factory", fit_plugin=f"{PLUGINS}:fitter_factory", camera_processes="per-camera")
    assert [s.name for s in specs] == ["camera-cam0", "camera-cam1", "camera-cam2", "segment", "track"]
    sup = Supervisor(specs, backoff_s=0.2, grace_s=5.0, cwd=str(REPO))
    stop = threading.Event()
    runner = threading.Thread(target=sup.run, args=(stop,), daemon=True)
    runner.start()
    poses: list[PoseRecord] = []
    killed_at = None
    try:
        end = time.monotonic() + 14.0
        while time.monotonic() < end:
            got = inbox.recv(0.1)
            if got is None:
                continue
            poses.append(got.message)
            if killed_at is None and sum(p.get("cameras") == 3 for p in poses) >= 10:
                os.kill(sup.pid("camera-cam2"), signal.SIGKILL)
                killed_at = len(poses)
            if killed_at is not None and sum(p.get("cameras") == 3 for p in poses[killed_at:]) >= 5:
                break
    finally:
        stop.set()
        runner.join(15.0)
        hub.close()
    assert killed_at is not None, f"only {len(poses)} poses before the kill"
    after = [p.get("cameras") for p in poses[killed_at:]]
    assert 2 in after, "no pose with the camera missing"
    first_two = after.index(2)
    assert 3 in after[first_two:], "the restarted camera never rejoined"
    cam2 = next(c for c in sup.children if c.spec.name == "camera-cam2")
    assert cam2.restarts >= 1 and cam2.history[0] == -signal.SIGKILL
    frames = [p.frame for p in poses]
    assert frames == sorted(frames) and len(set(frames)) == len(frames)  # live: newest only, never backwards
    assert all(sup.pid(c.spec.name) is None for c in sup.children)  # all stopped


def test_backoff_doubles_and_finished_is_not_restarted():
    t = [0.0]
    script = "import sys; sys.exit(int(sys.argv[1]))"
    specs = [ProcessSpec("crash", (sys.executable, "-c", script, "3")),
             ProcessSpec("done", (sys.executable, "-c", script, "0"))]
    sup = Supervisor(specs, backoff_s=1.0, max_backoff_s=3.0, stable_s=100.0, clock=lambda: t[0])
    sup.start()
    delays = []
    for _ in range(4):
        for c in sup.children:
            if c.proc is not None:
                c.proc.wait(10)
        sup.poll()
        crash = sup.children[0]
        delays.append(crash.restart_at_s - t[0])
        t[0] = crash.restart_at_s
        sup.poll()  # restarts it
    assert delays == [1.0, 2.0, 3.0, 3.0]
    assert sup.children[1].finished and sup.children[1].history == [0]
    assert sup.children[0].restarts == 4
    sup.stop()


def _processes_mentioning(text: str) -> list[int]:
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                if text in (proc / "cmdline").read_bytes().decode(errors="replace"):
                    pids.append(int(proc.name))
            except OSError:
                pass
    return pids


def test_run_command_streams_and_stops_everything_on_sigterm(tmp_path, rng):
    port = free_port()
    path = make_studio(tmp_path, rng, n_frames=200, delivery="live", port=port, studio="runcli")
    proc = subprocess.Popen([sys.executable, "-m", "service.commands.run", "--config", str(path), "--host", "h1",
                             "--start-delay-s", "2", "--segment-plugin", f"{PLUGINS}:segmenter_factory",
                             "--fit-plugin", f"{PLUGINS}:fitter_factory"], cwd=str(REPO), stderr=subprocess.PIPE,
                            text=True)
    try:
        client = open_session(ZenohSettings(connect=(f"tcp/127.0.0.1:{port}",), listen=("tcp/127.0.0.1:0",),
                                            connect_timeout_s=10.0))
        inbox = Inbox(client, Keys("runcli").pose, PoseRecord.from_bytes, mode="lossless", depth=1000)
        got = [inbox.recv(10.0) for _ in range(5)]
        client.close()
        assert all(g is not None for g in got), "no poses from `contourcap run`"
        cameras = 1 if (os.cpu_count() or 1) <= SMALL_HOST_CPUS else 3  # a small host: one camera process
        assert len(_processes_mentioning(str(path))) >= 3 + cameras  # run + cameras + segment + track
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-2000:]
    time.sleep(0.2)
    assert _processes_mentioning(str(path)) == [], "workers left running after SIGTERM"


def test_run_command_checks_the_session_before_starting_workers(tmp_path, capsys):
    """A missing session is one clear error (exit 2), not workers that fail and restart forever."""
    from service.commands import run

    path = tmp_path / "studio.toml"
    path.write_text(f'[studio]\nname = "pf"\nsession = "gone"\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
                    '[tracker]\nhost = "h1"\n[[camera]]\nname = "cam0"\nhost = "h1"\nbackend = "replay"\n')
    rc = run.main(["--config", str(path), "--host", "h1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert err == [f"contourcap run: {tmp_path / 'gone' / 'session.toml'}: session file not found"]


def test_run_command_names_an_uncalibrated_camera(tmp_path, rng, capsys):
    from service.commands import run

    make_studio(tmp_path, rng, n_frames=2, delivery="live", port=free_port())  # session: cam0..cam2, calibrated
    path = tmp_path / "studio2.toml"
    path.write_text(f'[studio]\nname = "pf2"\nsession = "session"\n[zenoh]\nlisten = ["tcp/127.0.0.1:{free_port()}"]\n'
                    '[tracker]\nhost = "h1"\n[[camera]]\nname = "cam0"\nhost = "h1"\nbackend = "replay"\n'
                    '[[camera]]\nname = "cam9"\nhost = "h2"\nbackend = "opencv"\nsource = "0"\n')
    rc = run.main(["--config", str(path), "--host", "h1"])
    err = capsys.readouterr().err
    assert rc == 2 and "no calibration for camera(s) ['cam9']" in err and "calibration.toml" in err
