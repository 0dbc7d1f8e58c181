"""Hostile-input benchmark (issue 16): a file-level sweep of bad inputs through the real CLI, and the
live demo studio under attack from a hostile zenoh peer on the loopback.

File sweep: every case writes one hostile input (random-bytes, truncated, empty or oversized videos;
TOML, JSONL and BVH of random bytes; a calibration for another image size; path escapes; bad options)
into a small session, keeps a valid output file where the command would write, and runs
``python -m service.cli ...`` in a subprocess.  A case is *clean* when it exits with its expected code,
prints no traceback and no "unexpected" line, and ends its stderr with one line naming the problem;
a *lost file* is an existing output that is not byte-for-byte unchanged afterwards.

Live attack (``--live``, default on): ``contourcap demo --live`` twice on the same rendered studio —
clean, then while a hostile peer publishes, for a bounded time and count, malformed frames, chamfers,
have and demand notices, 5 MB frames, far-future frame ids (10^12) and floods of notices on the
studio's keys.  ``poses_per_s`` of both runs, the workers' ``rejected``/``bad`` counters (their status
messages), and ``max_rss_mb`` (largest resident set of any child process) are reported.

    python bench/hostile.py [--json] [--no-live | --no-sweep] [--duration-s 15] [--cameras 4] [--runs 2]

Prints ``{"cases", "clean_errors", "tracebacks", "files_lost", "poses_per_s_clean",
"poses_per_s_under_attack", "max_rss_mb", "rejected_messages", "machine_ref_ms"}`` (``--json``) and,
without ``--json``, one line per case.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from service.blas import pin_blas_threads  # noqa: E402

pin_blas_threads()

import argparse  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import tempfile  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from typing import Callable  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from machine_ref import machine_ref_ms  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
SIZE = (64, 48)
N_FRAMES = 6
PROTECTED = b'{"frame": 0, "ok": false, "reason": "an earlier take"}\n' * 4
FAR = 10**12


# --- the file sweep ------------------------------------------------------------------------------

def _random_images(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    return [rng.integers(0, 256, (SIZE[1], SIZE[0], 3), dtype=np.uint8) for _ in range(n)]


def _write_video(path: Path, images) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, SIZE)
    for img in images:
        writer.write(img)
    writer.release()


def make_session(root: Path, rng: np.random.Generator, cams=("cam0", "cam1")) -> Path:
    """A small valid session of random images (videos, backgrounds, calibration) in ``root``."""
    from capture.calibration import save_calibration
    from capture.camera import Camera
    from capture.session import write_session_toml

    root.mkdir(parents=True)
    (root / "background").mkdir()
    entries, calib = [], []
    for i, name in enumerate(cams):
        _write_video(root / f"{name}.avi", _random_images(rng, N_FRAMES))
        _write_video(root / "background" / f"{name}.avi", _random_images(rng, 3))
        entries.append({"name": name, "video": f"{name}.avi", "background": f"background/{name}.avi"})
        a = 2 * np.pi * i / len(cams)
        calib.append(Camera.look_at(name, (3 * np.cos(a), 3 * np.sin(a), 1.5), (0, 0, 1), size=SIZE))
    write_session_toml(root, name="hostile", fps=25.0, cameras=entries, height_m=1.7)
    save_calibration(root / "calibration.toml", calib)
    return root


@dataclass
class Case:
    """One hostile input: ``setup(tmp, session) -> argv`` (after ``contourcap``); ``outputs`` are files
    (relative to tmp) that hold a valid earlier output before the run and must be unchanged after it."""

    name: str
    setup: Callable[[Path, Path, np.random.Generator], list[str]]
    outputs: tuple[str, ...] = ("poses.jsonl",)
    expect_rc: int = 2
    expect_in_err: str = ""


def _replace_in(path: Path, old: str, new: str) -> None:
    path.write_text(path.read_text().replace(old, new))


def _cut(path: Path, keep: float) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def _track(s: Path, t: Path, *extra: str) -> list[str]:
    return ["track", str(s), "--out", str(t / "poses.jsonl"), *extra]


def _poses(t: Path, body: bytes) -> Path:
    p = t / "in.jsonl"
    p.write_bytes(body)
    return p


_POSE = (b'{"frame": %d, "timestamp_ns": %d, "ok": true, "joints": {"pelvis": [0.0, 0.0, 1.0]}}')


def cases() -> list[Case]:
    """The sweep (each case a failure mode of issue 16 or one like it)."""
    def rand_video(s, t, rng):
        (s / "cam1.avi").write_bytes(rng.bytes(20_000))
        return _track(s, t)

    def empty_video(s, t, rng):
        (s / "cam1.avi").write_bytes(b"")
        return _track(s, t)

    def cut_video(s, t, rng):
        _cut(s / "cam1.avi", 0.4)
        return _track(s, t)

    def oversized_video(s, t, rng):
        with open(s / "cam1.avi", "wb") as fh:  # 64 MB of zeros: not a video, and big
            fh.truncate(64 << 20)
        return _track(s, t)

    def rand_background(s, t, rng):
        (s / "background" / "cam0.avi").write_bytes(rng.bytes(5000))
        return _track(s, t)

    def short_camera(s, t, rng):
        _write_video(s / "cam1.avi", _random_images(rng, 2))
        return _track(s, t)

    def rand_session(s, t, rng):
        (s / "session.toml").write_bytes(rng.bytes(400))
        return _track(s, t)

    def rand_calibration(s, t, rng):
        (s / "calibration.toml").write_bytes(b"\xff" + rng.bytes(400))
        return _track(s, t)

    def wrong_size_calibration(s, t, rng):
        _replace_in(s / "calibration.toml", "size = [64, 48]", "size = [640, 480]")
        return _track(s, t)

    def escape_dotdot(s, t, rng):
        _replace_in(s / "session.toml", 'video = "cam1.avi"', 'video = "../../../etc/passwd"')
        return _track(s, t)

    def escape_absolute(s, t, rng):
        _replace_in(s / "session.toml", 'video = "cam1.avi"', 'video = "/etc/passwd"')
        return _track(s, t)

    def frames_past_end(s, t, rng):
        return _track(s, t, "--frames", "100:200")

    def frames_malformed(s, t, rng):
        return _track(s, t, "--frames", "x:y")

    def replay_random_video(s, t, rng):
        (s / "cam0.avi").write_bytes(rng.bytes(3000))
        return ["replay", str(s)]

    def studio_random(cmd):
        def setup(s, t, rng):
            (t / "studio.toml").write_bytes(b"\xfe" + rng.bytes(300))
            return [cmd, "--config", str(t / "studio.toml")]
        return setup

    def export_random(s, t, rng):
        return ["export", str(_poses(t, rng.bytes(2000))), "--csv", str(t / "out.csv")]

    def export_cut_line(s, t, rng):
        body = b"\n".join(_POSE % (k, k * 40_000_000) for k in range(4)) + b"\n" + (_POSE % (4, 0))[:20]
        return ["export", str(_poses(t, body)), "--csv", str(t / "out.csv")]

    def export_all_lost(s, t, rng):
        body = b"".join(b'{"frame": %d, "timestamp_ns": 0, "ok": false, "reason": "lost"}\n' % k for k in range(3))
        return ["export", str(_poses(t, body)), "--bvh", str(t / "out.bvh")]

    def export_fps_zero(s, t, rng):
        return ["export", str(_poses(t, _POSE % (0, 0) + b"\n")), "--csv", str(t / "out.csv"), "--fps", "0"]

    def export_escape_reason(s, t, rng):
        body = b'{"frame": 0, "timestamp_ns": 0, "ok": false, "reason": "\\u001b[2J\\u001b]0;x\\u0007"}\n'
        return ["export", str(_poses(t, body + b"\x1b[31mnot json\n")), "--csv", str(t / "out.csv")]

    def synth_random_bvh(s, t, rng):
        (t / "m.bvh").write_bytes(rng.bytes(1000))
        return ["synth", str(t / "m.bvh"), str(t / "synth_out")]

    def demo_bad_motion(s, t, rng):
        return ["demo", "--motion", "nope", "--cache", str(t / "cache")]

    def review_random_poses(s, t, rng):
        return ["review", str(s), str(_poses(t, rng.bytes(500))), "--out", str(t / "review.mp4")]

    return [
        Case("track: random-bytes video", rand_video),
        Case("track: empty video", empty_video),
        Case("track: video cut to 40 %", cut_video),
        Case("track: 64 MB non-video", oversized_video),
        Case("track: random-bytes background video", rand_background),
        Case("track: a camera 2 of 6 frames long", short_camera, expect_in_err="--allow-missing-cameras"),
        Case("track: session.toml of random bytes", rand_session),
        Case("track: calibration.toml of random bytes", rand_calibration),
        Case("track: calibration for 640x480, videos 64x48", wrong_size_calibration),
        Case("track: ../../../etc/passwd video", escape_dotdot, expect_in_err="leaves the session folder"),
        Case("track: /etc/passwd video", escape_absolute, expect_in_err="leaves the session folder"),
        Case("track: --frames 100:200 past the end", frames_past_end, expect_in_err="6 frames"),
        Case("track: --frames x:y", frames_malformed),
        Case("replay: random-bytes video", replay_random_video, outputs=(), expect_rc=1),
        Case("run: studio.toml of random bytes", studio_random("run"), outputs=()),
        Case("view: studio.toml of random bytes", studio_random("view"), outputs=()),
        Case("echo: studio.toml of random bytes", studio_random("echo"), outputs=()),
        Case("export: JSONL of random bytes", export_random, outputs=("out.csv",)),
        Case("export: last line cut short", export_cut_line, outputs=(), expect_rc=0, expect_in_err="cut short"),
        Case("export: every frame lost", export_all_lost, outputs=("out.bvh",), expect_in_err="in.jsonl"),
        Case("export: --fps 0", export_fps_zero, outputs=("out.csv",)),
        Case("export: escapes in a bad line", export_escape_reason, outputs=("out.csv",)),
        Case("synth: BVH of random bytes", synth_random_bvh, outputs=()),
        Case("demo: --motion nope", demo_bad_motion, outputs=(), expect_in_err="nope"),
        Case("review: poses of random bytes", review_random_poses, outputs=("review.mp4",)),
    ]


@dataclass
class CaseResult:
    name: str
    rc: int
    clean: bool
    traceback: bool
    files_lost: int
    last_line: str
    seconds: float


def run_case(case: Case, tmp: Path, rng: np.random.Generator) -> CaseResult:
    """Run one case in a subprocess; see the module docstring for *clean* and *lost*."""
    session = make_session(tmp / "session", rng)
    argv = case.setup(session, tmp, rng)
    for rel in case.outputs:
        (tmp / rel).write_bytes(PROTECTED)
    env = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1"}
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "service.cli", *argv], cwd=tmp, env=env, stdin=subprocess.DEVNULL,
                          capture_output=True, timeout=300)
    seconds = time.perf_counter() - t0
    err = proc.stderr.decode("utf-8", "replace")
    lines = [ln for ln in err.replace("\r", "\n").splitlines() if ln.strip()]
    last = lines[-1] if lines else ""
    traceback = "Traceback" in err or "unexpected" in err
    lost = sum((tmp / rel).read_bytes() != PROTECTED if (tmp / rel).exists() else 1 for rel in case.outputs)
    clean = (proc.returncode == case.expect_rc and not traceback and bool(last)
             and "\x1b" not in err and (case.expect_in_err in err))
    return CaseResult(case.name, proc.returncode, clean, traceback, lost, last[:200], seconds)


def file_sweep(seed: int = 16) -> list[CaseResult]:
    rng = np.random.default_rng(seed)
    out = []
    for case in cases():
        with tempfile.TemporaryDirectory(prefix="hostile-") as tmp:
            out.append(run_case(case, Path(tmp), rng))
    return out


# --- the live attack -----------------------------------------------------------------------------

@dataclass
class Attack:
    """A hostile peer on the demo's loopback hub (bounded: ``duration_s`` and ``max_messages``)."""

    port: int
    cameras: tuple[str, ...]
    duration_s: float
    max_messages: int = 20_000
    hostile: bool = True  # False: only listen to the workers' status (the clean run)
    sent: int = 0
    status: dict = field(default_factory=dict)

    def run(self, stop: threading.Event) -> None:
        from service.demo import STUDIO
        from service.wire.bus import Keys, ZenohSettings, open_session
        from service.wire.messages import FrameMessage
        from service.wire.records import DemandMessage, HaveMessage, StatusMessage

        keys = Keys(STUDIO)
        rng = np.random.default_rng(7)
        # wait for the hub to listen
        for _ in range(200):
            if stop.is_set():
                return
            try:
                session = open_session(ZenohSettings.loopback(self.port, listen=False))
                break
            except Exception:  # noqa: BLE001 - the hub is not up yet
                time.sleep(0.1)
        else:
            return

        def on_status(sample) -> None:
            try:
                msg = StatusMessage.from_bytes(sample.payload.to_bytes())
            except Exception:  # noqa: BLE001
                return
            self.status[msg.component] = dict(msg.stats)

        sub = session.declare_subscriber(keys.status("*"), on_status)
        big = FrameMessage.from_image(self.cameras[0], FAR, 0, rng.integers(0, 256, (1200, 1400, 3), np.uint8))
        big_bytes = big.to_bytes()  # ~5 MB, far-future id
        t_end = time.monotonic() + self.duration_s
        try:
            while not self.hostile and not stop.is_set() and time.monotonic() < t_end:
                time.sleep(0.1)
            while self.hostile and not stop.is_set() and time.monotonic() < t_end and self.sent < self.max_messages:
                for cam in self.cameras:
                    session.put(keys.frame(cam), rng.bytes(int(rng.integers(1, 2000))))  # malformed
                    session.put(keys.chamfer(cam), rng.bytes(200))
                    session.put(keys.have(cam), HaveMessage(cam, (FAR, FAR - 1)).to_bytes())  # far future
                    session.put(keys.have(cam), b'{"v": 1, "camera": "\x1b[2J", "frames": [1]}')
                    self.sent += 4
                session.put(keys.demand("track"), DemandMessage("track", FAR).to_bytes())
                session.put(keys.pose, b'{"frame": 1, "timestamp_ns": 0, "ok": false, "reason": "\x1b]0;pwn\x07"}')
                self.sent += 2
                if self.sent % 200 < 6:  # an oversized frame now and then (a few per second)
                    session.put(keys.frame(self.cameras[0]), big_bytes)
                    self.sent += 1
                for _ in range(20):  # a flood of notices
                    session.put(keys.have(self.cameras[-1]), HaveMessage(self.cameras[-1], (FAR + 1,)).to_bytes())
                self.sent += 20
                time.sleep(0.01)
            # linger to read the workers' last status
            time.sleep(1.5)
        finally:
            sub.undeclare()
            session.close()


def live(duration_s: float, cameras: int, *, stub_fitter: bool = False, runs: int = 1) -> dict:
    """Poses per second of the live demo, clean and under attack, and the workers' rejected counts.

    ``runs`` pairs back to back, the order alternating (clean first, then attack first) so that
    neither side always runs first; the figures are the medians, each run's in ``*_runs``."""
    from dataclasses import replace

    from service.commands import demo as demo_cmd
    from service.demo import run_demo
    from service.wire.bus import free_port

    parser = argparse.ArgumentParser()
    demo_cmd.add_args(parser)
    result: dict = {"poses_per_s_clean_runs": [], "poses_per_s_under_attack_runs": [], "ok_clean_runs": [],
                    "ok_under_attack_runs": [], "machine_ref_ms_runs": [], "loadavg_1min_runs": []}
    if not stub_fitter:  # numba's disk cache filled first: else the first run pays for compiling
        from tracker.fitting.warmup import warm_up

        warm_up()
    for i in range(max(1, runs)):
        result["machine_ref_ms_runs"].append(round(machine_ref_ms(), 2))
        result["loadavg_1min_runs"].append(round(os.getloadavg()[0], 2))
        for label in ("clean", "under_attack")[::1 if i % 2 == 0 else -1]:
            with tempfile.TemporaryDirectory(prefix="hostile-live-") as tmp:
                args = parser.parse_args(["--live", "--duration-s", str(duration_s), "--cameras", str(cameras),
                                          "--out", tmp] + (["--fit-plugin", "tests.support.plugins:fitter_factory"]
                                                           if stub_fitter else []))
                opts = replace(demo_cmd.options_from_args(args), port=free_port())
                stop = threading.Event()
                attack = Attack(opts.port, tuple(f"cam{i}" for i in range(cameras)),
                                duration_s=opts.live_start_delay_s + duration_s + 5, hostile=label == "under_attack")
                thread = threading.Thread(target=attack.run, args=(stop,), daemon=True)
                thread.start()
                try:
                    summary = run_demo(opts, progress=lambda m: print(m, file=sys.stderr))
                finally:
                    stop.set()
                result[f"poses_per_s_{label}_runs"].append(summary.poses_per_s)
                result[f"ok_{label}_runs"].append(summary.ok)
                thread.join(10)
                refused = int(sum(v for comp in attack.status.values() for k, v in comp.items()
                                  if k in ("rejected", "bad", "mismatched_key", "unknown")))
                if label == "under_attack":
                    result["attack_messages"] = attack.sent
                    result["worker_status"] = attack.status
                    result["rejected_messages"] = refused
                else:
                    result["rejected_messages_clean"] = refused  # a clean studio refuses nothing
                    result["worker_status_clean"] = attack.status
    for label in ("clean", "under_attack"):
        rates = [r for r in result[f"poses_per_s_{label}_runs"] if r is not None]
        result[f"poses_per_s_{label}"] = float(np.median(rates)) if rates else None
        result[f"ok_{label}"] = result[f"ok_{label}_runs"][-1]
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", action="store_true", help="print one JSON object")
    ap.add_argument("--no-live", action="store_true", help="the file sweep only")
    ap.add_argument("--no-sweep", action="store_true", help="the live attack only")
    ap.add_argument("--duration-s", type=float, default=15.0, help="live: replay window of each demo run")
    ap.add_argument("--cameras", type=int, default=4, help="live: demo cameras")
    ap.add_argument("--runs", type=int, default=1,
                    help="live: clean/attack pairs, back to back, the order alternating (figures: medians)")
    ap.add_argument("--stub-fitter", action="store_true",
                    help="live: a trivial fitter plug-in (tests.support.plugins) instead of the tracker, so the "
                         "figure is the transport and segmentation under attack, not the tracker's luck")
    opts = ap.parse_args(argv)
    ref = machine_ref_ms()
    t0 = time.perf_counter()
    results = [] if opts.no_sweep else file_sweep()
    sweep_s = time.perf_counter() - t0
    out = {"cases": len(results), "clean_errors": sum(r.clean for r in results),
           "tracebacks": sum(r.traceback for r in results), "files_lost": sum(r.files_lost for r in results),
           "poses_per_s_clean": None, "poses_per_s_under_attack": None, "max_rss_mb": None,
           "rejected_messages": None, "machine_ref_ms": round(ref, 2), "sweep_s": round(sweep_s, 1),
           "unclean": [f"{r.name}: rc {r.rc}: {r.last_line}" for r in results if not r.clean]}
    if not opts.no_live:
        out.update(live(opts.duration_s, opts.cameras, stub_fitter=opts.stub_fitter, runs=opts.runs))
    out["max_rss_mb"] = round(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024, 1)
    if opts.json:
        print(json.dumps(out))
    else:
        for r in results:
            print(f"{'ok   ' if r.clean else 'FAIL '} rc {r.rc}  {r.seconds:5.1f} s  {r.name}: {r.last_line}")
        print(json.dumps({k: v for k, v in out.items() if k not in ("worker_status",)}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
