"""``contourcap demo``: a synthetic studio end to end over zenoh on loopback.

1. A demo session is rendered once from a CMU BVH bundled with the package (``service.synthetic_session``) and
   cached under ``cache_dir`` (keyed by its options).
2. A studio config for it is written to ``out_dir`` (replay cameras, loopback peer hub, multicast
   off); the camera, segment and track workers run as processes under the :class:`Supervisor`.
   Lossless: every frame once, in order.  Live: the clip loops in real time for ``live_duration_s``
   and the tracker takes the newest complete frame set (stale ones dropped).  The clip plays its
   motion forward then backward (``bounce``), so the loop is continuous: a plain looped clip makes
   the subject jump from the last pose to the first (0.5–0.9 m for the hop) once per pass, which no
   person does.  Live, the replay cameras hold the clip decoded in memory, as a camera delivers
   decoded frames (``live_preload_mb``), when it fits.
3. This process is the hub and the client: it records every pose (``poses.jsonl``), bridges poses,
   images and silhouettes to rerun (``demo.rrd``) and exports ``poses.bvh``.  Lossless, it taps
   every camera's frames and silhouettes; live, only the first ``live_image_cameras`` cameras' (a tap
   decodes every frame of its cameras in this process, which competes with the pipeline:
   docs/tuning.md; a silhouette tap makes the segment worker send each chamfer twice), every
   ``image_every``-th frame logged.  Poses always.
4. The summary: frames, ``fps_out`` (between the first and the last pose: a burst after a slow start
   reads as real time), ``poses_per_s`` (live: poses over the replay window), latency p50/p99, median
   rms_px, mean joint error against the session's ``ground_truth.jsonl`` (joints both records name,
   ok frames), dropped sets, live: the tracker's ``demand_timeouts`` and ``missing_cameras`` (from its
   last status), paths.
"""

from __future__ import annotations

import hashlib
import json
import os
import resource
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from service.atomic import write_text_atomic
from service.wire.bus import Inbox, Keys, ZenohSettings, free_port, open_session
from service.wire.records import PoseRecord, StatusMessage

STUDIO = "demo"
HOST = "demo"


@dataclass(frozen=True)
class DemoOptions:
    """What ``contourcap demo`` renders and runs.

    Attributes
    ----------
    cameras, size, frames, fps, motion
        The synthetic session: camera count, image size (w, h) in pixels, frames of motion, frames
        per second, bundled CMU motion name.
    bounce : bool
        The session holds the motion forward then backward (``2 * frames - 2`` frames;
        ``tracker.synthetic.retarget.palindrome``), else forward only.
    delivery : {"lossless", "live"}
    out_dir, cache_dir : Path
        Outputs (poses, BVH, rrd); rendered sessions, keyed by their options.
    image_every : int
        Log every n-th frame's images to rerun.
    timeout_s : float
        Give up after this long (seconds).
    live_start_delay_s, live_duration_s : float
        Live: seconds until session time 0 is due (the workers start meanwhile); seconds of replay.
    live_image_cameras : int
        Live: cameras whose frames and silhouettes are tapped for rerun (default none: poses only).
    live_preload_mb : float
        Live: the replay cameras decode the clip into memory first when it takes at most this many
        MB decoded (0: never; they then decode the session's videos while streaming).
    segment_plugin, fit_plugin : str or None
        ``module:callable`` replacing the segmenter or the tracker.
    """

    cameras: int = 6
    size: tuple[int, int] = (320, 240)
    frames: int = 90
    fps: float = 30.0
    motion: str = "scaled_131_03"
    bounce: bool = True
    delivery: str = "lossless"
    out_dir: Path | None = None  # None: <cache_dir>/last-demo (never the working directory)
    cache_dir: Path = Path.home() / ".cache" / "contourcap"
    image_every: int = 5
    timeout_s: float = 1800.0
    live_start_delay_s: float = 8.0
    live_duration_s: float = 20.0
    live_image_cameras: int = 0
    live_preload_mb: float = 1024.0
    segment_plugin: str | None = None
    fit_plugin: str | None = None
    port: int | None = None  # the loopback hub's TCP port (None: a free one)


@dataclass(frozen=True)
class DemoSummary:
    """The demo's result (the module docstring lists what each figure measures).

    Times in seconds unless the name says ``_ms``; ``fps_*`` and ``poses_per_s`` per second of wall
    time; ``mean_joint_error_m`` in metres; paths as strings; None where a figure does not apply;
    ``replay_ns``: live, the wall-clock nanoseconds (``time.time_ns``) of session time 0 and of the
    replay's end.
    """

    frames: int
    ok: int
    cameras: int
    fps_in: float
    fps_out: float
    realtime_factor: float
    poses_per_s: float | None
    latency_ms_p50: float | None
    latency_ms_p99: float | None
    median_rms_px: float | None
    mean_joint_error_m: float | None
    dropped_sets: int
    demand_timeouts: int | None
    missing_cameras: int | None
    cpu_percent: float
    wall_s: float
    session: str
    poses: str
    bvh: str | None
    rrd: str
    replay_ns: tuple[int, int] | None = None

    def as_dict(self) -> dict:
        """The fields as a JSON-ready dict."""
        return asdict(self)


def session_frames(opts: DemoOptions) -> int:
    """Frames in the demo session of ``opts`` (the motion's, doubled less two when it bounces)."""
    return 2 * opts.frames - 2 if opts.bounce and opts.frames >= 3 else opts.frames


def decoded_clip_mb(opts: DemoOptions) -> float:
    """Megabytes (1e6 bytes) of the demo session's frames decoded (BGR, all cameras)."""
    return session_frames(opts) * opts.cameras * opts.size[0] * opts.size[1] * 3 / 1e6


def preload_seconds(session, opts: DemoOptions) -> float:
    """Seconds the replay cameras take to decode the demo clip into memory (side by side, one per
    CPU), estimated by decoding the first frames of one camera here."""
    from itertools import islice

    from capture.replay import read_frames

    frames = read_frames(session, session.camera_names[0])
    t0 = time.perf_counter()
    n = sum(1 for _ in islice(frames, 3))
    per_frame = (time.perf_counter() - t0) / max(1, n)
    frames.close()
    return per_frame * session_frames(opts) * opts.cameras / min(opts.cameras, os.cpu_count() or 1)


def demo_session(opts: DemoOptions, *, progress: Callable[[str], None] = print) -> Path:
    """The cached synthetic session for ``opts`` (rendered on first use)."""
    from service.synthetic_session import make_synthetic_session
    from tracker.synthetic.bvh import load_bvh
    from tracker.synthetic.retarget import palindrome, retarget_bvh
    from tracker.synthetic.synth import bundled_motion

    # the model file is in the key: its ground truth joints are the model's (a changed joint table re-renders)
    from tracker.body.model import MODELS_DIR

    model_file = MODELS_DIR / "knossow40.toml"
    key = json.dumps([opts.motion, opts.cameras, list(opts.size), opts.frames, opts.fps]
                     + (["bounce"] if opts.bounce else [])
                     + [hashlib.sha1(model_file.read_bytes()).hexdigest()], sort_keys=True)
    root = Path(opts.cache_dir) / f"demo-{hashlib.sha1(key.encode()).hexdigest()[:12]}"
    if (root / "ground_truth.jsonl").is_file() and (root / "session.toml").is_file():
        progress(f"demo session (cached): {root}")
        return root
    bvh = bundled_motion(opts.motion)
    motion = retarget_bvh(load_bvh(bvh), fps=opts.fps, frames=opts.frames)
    if opts.bounce:
        motion = palindrome(motion)
    progress(f"rendering the demo session ({opts.cameras} cameras, {motion.n_frames} frames) into {root} ...")
    make_synthetic_session(bvh, root, cameras=opts.cameras, size=tuple(opts.size), retargeted=motion,
                           fps=opts.fps, seed=0, name="demo",
                           progress=lambda d, n: progress(f"  rendered {d}/{n}") if d % 10 == 0 or d == n else None)
    return root


def write_studio(session_root: Path, out_dir: Path, *, port: int, delivery: str) -> Path:
    """A studio config replaying ``session_root`` on one host over a loopback peer hub."""
    from capture.session import load_session
    from capture.tomlio import dumps

    session = load_session(session_root)
    data = {"studio": {"name": STUDIO, "delivery": delivery, "session": str(session_root.resolve())},
            "zenoh": {"listen": [f"tcp/127.0.0.1:{port}"]},
            # the demo's subject is rendered from the model at the session's height: nothing to calibrate
            "tracker": {"host": HOST, "set_timeout_ms": 200, "window": 4, "auto_subject": False},
            "camera": [{"name": c, "host": HOST, "backend": "replay", "encoding": "raw"}
                       for c in session.camera_names]}
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "studio.toml"
    write_text_atomic(path, dumps(data))
    return path


def joint_error(poses: list[PoseRecord], truth_path: Path) -> float | None:
    """Mean distance (m) between estimated and true joints over ok frames and shared joint names
    (frame ids of looped replays are folded back onto the clip)."""
    truth = {}
    for line in truth_path.read_text().splitlines():
        if line.strip():
            rec = json.loads(line)
            truth[rec["frame"]] = rec.get("joints", {})
    if not truth:
        return None
    first, period = min(truth), max(truth) - min(truth) + 1  # a looped replay adds k * period to the ids
    errs = []
    for p in poses:
        gt = truth.get(first + (p.frame - first) % period)
        if not p.ok or not gt:
            continue
        names = [n for n in p.joints if n in gt]
        if names:
            est = np.array([p.joints[n] for n in names])
            errs.append(np.linalg.norm(est - np.array([gt[n] for n in names]), axis=1))
    return float(np.concatenate(errs).mean()) if errs else None


def _cpu_s() -> float:
    """CPU seconds used so far by this process and its finished children."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    mine = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime + mine.ru_utime + mine.ru_stime


def _pct(values, q) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None


def run_demo(opts: DemoOptions, *, progress: Callable[[str], None] = print) -> DemoSummary:
    """Run the whole demo (see module docstring); returns its summary."""
    import rerun as rr

    from capture.session import load_session
    from service.config import load_config
    from service.export import ExportError, write_bvh, write_pose_records
    from service.wire.messages import ChamferMessage, FrameMessage
    from service.flow.supervisor import Supervisor, plan_host
    from service.viewer import RerunBridge

    session_root = demo_session(opts, progress=progress)
    session = load_session(session_root)
    out = Path(opts.out_dir) if opts.out_dir is not None else Path(opts.cache_dir) / "last-demo"
    port = free_port() if opts.port is None else int(opts.port)
    cfg_path = write_studio(session_root, out, port=port, delivery=opts.delivery)
    cfg = load_config(cfg_path)
    n_total = session_frames(opts)
    hub = open_session(ZenohSettings.loopback(port, listen=True))
    keys = Keys(STUDIO)
    poses_in = Inbox(hub, keys.pose, PoseRecord.from_bytes, mode="lossless", depth=1_000_000)
    status_in = Inbox(hub, keys.status("track"), StatusMessage.from_bytes, mode="live", depth=4)
    rrd = out / "demo.rrd"
    rec = rr.RecordingStream("contourcap", recording_id="contourcap-demo")
    rec.save(str(rrd))
    bridge = RerunBridge(rec, cameras=list(session.calibration), image_every=opts.image_every)
    live = opts.delivery == "live"
    # live: frames of a few cameras only (decoding every frame here competes with the pipeline)
    imaged = list(session.camera_names)[:max(0, opts.live_image_cameras)] if live else ["*"]
    taps = [(Inbox(hub, keys.frame(c), FrameMessage.from_bytes, depth=2 * opts.cameras), bridge.on_frame)
            for c in imaged]
    # and the silhouettes of those cameras only: a subscriber here makes each segment worker send its chamfers
    # twice, and this process decode them
    taps += [(Inbox(hub, keys.chamfer(c), ChamferMessage.from_bytes, depth=2 * opts.cameras), bridge.on_chamfer)
             for c in imaged]
    if live and opts.fit_plugin is None:
        # numba's disk cache filled (or loaded) here, before session time 0 is set: on a fresh checkout the
        # track worker's own warm-up would compile for longer than the start delay and miss the replay's start
        from tracker.fitting.warmup import warm_up

        progress(f"tracker kernels compiled or loaded in {warm_up():.1f} s")
    decoded_mb = decoded_clip_mb(opts)
    preload = live and 0 < decoded_mb <= opts.live_preload_mb
    # live: session time 0 is due once the workers are up and the cameras hold the clip (frames already
    # late at a camera are skipped)
    delay_s = opts.live_start_delay_s + (1.5 * preload_seconds(session, opts) if preload else 0.0)
    epoch = time.time_ns() + int(delay_s * 1e9) if live else None
    end_ns = None
    specs = plan_host(cfg, str(cfg_path), HOST, hub=f"tcp/127.0.0.1:{port}", epoch_ns=epoch, idle_exit_s=5.0,
                      segment_plugin=opts.segment_plugin, fit_plugin=opts.fit_plugin, loop_replay=live,
                      preload_replay=preload)
    sup = Supervisor(specs, backoff_s=0.5, max_backoff_s=2.0)
    poses: list[PoseRecord] = []
    last_status: StatusMessage | None = None
    t0 = time.monotonic()
    cpu0 = _cpu_s()  # the rendering and set-up before t0 are not the pipeline's
    first_pose_t = last_pose_t = None
    progress(f"starting {len(specs)} worker processes ({opts.delivery}"
             + (f", cameras holding the clip decoded: {decoded_mb:.0f} MB" if preload else "")
             + (f", session time 0 in {delay_s:.1f} s" if live else "")
             + f"), zenoh hub tcp/127.0.0.1:{port}")
    sup.start()
    try:
        last_report = 0.0
        while time.monotonic() - t0 < opts.timeout_s and not sup.all_finished:
            sup.poll()
            got = poses_in.recv(0.05)
            while got is not None:
                now = time.monotonic()
                first_pose_t = first_pose_t or now
                last_pose_t = now
                poses.append(got.message)
                bridge.on_pose(got.message)
                got = poses_in.recv(0) if len(poses_in) else None
            for inbox, handle in taps:
                for item in inbox.drain():
                    handle(item.message)
            for item in status_in.drain():
                last_status = item.message
            if time.monotonic() - last_report > 2.0 and poses:
                last_report = time.monotonic()
                lat = [p.get("latency_ms") for p in poses[-30:] if p.get("latency_ms") is not None]
                progress(f"  {len(poses)}/{n_total} poses, {sum(p.ok for p in poses)} ok"
                         + (f", latency {np.median(lat):.0f} ms" if lat else ""))
            if opts.delivery == "lossless" and len(poses) >= n_total:
                break
            if live and time.time_ns() > epoch + int(opts.live_duration_s * 1e9):
                break  # live: the looped replay ran for live_duration_s
    finally:
        end_ns = time.time_ns()
        sup.stop()
        time.sleep(0.2)  # the workers' last status messages
        for item in status_in.drain():
            last_status = item.message
        for inbox, _ in taps + [(poses_in, None), (status_in, None)]:
            inbox.close()
        hub.close()
        rec.flush()
        rec.disconnect()
    wall = time.monotonic() - t0
    cpu = _cpu_s() - cpu0
    poses_path = out / "poses.jsonl"
    write_pose_records(poses_path, poses)
    bvh = None
    if any(p.ok and p.get("params") for p in poses):
        from tracker.body.model import ModelError
        from service.offline import session_model

        try:
            bvh = str(write_bvh(out / "poses.bvh", session_model(session, poses[0].get("model") or "knossow40"),
                                poses, fps=session.fps).path)
        except (ExportError, ModelError) as exc:
            progress(f"no BVH: {exc}")
    lat = [p.get("latency_ms") for p in poses if p.get("latency_ms") is not None]
    rms = [p.get("rms_px") for p in poses if p.ok and p.get("rms_px") is not None]
    span = (last_pose_t - first_pose_t) if first_pose_t and last_pose_t and len(poses) > 1 else 0.0
    fps_out = (len(poses) - 1) / span if span > 0 else 0.0
    fps_in = session.fps
    stats = last_status.stats if last_status is not None else {}
    dropped = int(stats.get("stale_sets", 0))
    window_s = min(opts.live_duration_s, (end_ns - epoch) / 1e9) if live else 0.0  # the replay ran in it

    def live_count(name: str) -> int | None:
        return int(stats[name]) if live and name in stats else None

    return DemoSummary(
        frames=len(poses), ok=sum(p.ok for p in poses), cameras=opts.cameras, fps_in=fps_in, fps_out=fps_out,
        realtime_factor=fps_out / fps_in if fps_in else 0.0,
        poses_per_s=len(poses) / window_s if window_s > 0 else None, latency_ms_p50=_pct(lat, 50),
        latency_ms_p99=_pct(lat, 99), median_rms_px=float(np.median(rms)) if rms else None,
        mean_joint_error_m=joint_error(poses, session_root / "ground_truth.jsonl"), dropped_sets=dropped,
        demand_timeouts=live_count("demand_timeouts"), missing_cameras=live_count("missing_cameras"),
        cpu_percent=100.0 * cpu / wall if wall > 0 else 0.0, wall_s=wall, session=str(session_root),
        poses=str(poses_path), bvh=bvh, rrd=str(rrd),
        replay_ns=(epoch, epoch + int(window_s * 1e9)) if live else None)
