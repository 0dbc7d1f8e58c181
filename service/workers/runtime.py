"""Building a worker's parts from the studio config (sources, segmenters, fitter, zenoh settings),
plug-in loading and signal handling.  Used by ``service/commands/worker.py`` and the supervisor.

Single-host peer mode: the supervisor opens a *hub* session listening on ``[zenoh] listen``
(default ``tcp/127.0.0.1:7447``); each worker is a peer that connects to the hub and listens on an
ephemeral loopback port, so gossip scouting meshes the workers with each other (multicast off).
Multi-host: ``mode = "client"`` and ``connect`` to ``contourcap router``; the workers use
``[zenoh]`` as written.
"""

from __future__ import annotations

import importlib
import logging
import signal
import threading
from dataclasses import replace
from typing import Callable

from service.wire.bus import ZenohSettings
from service.config import ConfigError, StudioConfig

log = logging.getLogger("contourcap.runtime")
DEFAULT_HUB = "tcp/127.0.0.1:7447"


def hub_endpoint(cfg: StudioConfig) -> str:
    """Where this host's workers connect in peer mode (the hub's first listen endpoint, on loopback)."""
    ep = cfg.zenoh.listen[0] if cfg.zenoh.listen else DEFAULT_HUB
    proto, _, addr = ep.partition("/")
    host, _, port = addr.rpartition(":")
    if host in ("0.0.0.0", "[::]", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def worker_settings(cfg: StudioConfig, hub: str | None) -> ZenohSettings:
    """Zenoh settings of a worker: a loopback peer of ``hub``, or ``[zenoh]`` as written."""
    if hub is None:
        return cfg.zenoh
    return replace(cfg.zenoh, mode="peer", connect=(hub,), listen=("tcp/127.0.0.1:0",), config_file=None)


def load_plugin(spec: str) -> Callable:
    """``module:callable`` -> the callable (a local, user-given plug-in; never from the network)."""
    mod, _, attr = spec.partition(":")
    if not mod or not attr:
        raise ConfigError(f"plug-in {spec!r}: expected 'module:callable'")
    try:
        obj = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"plug-in {spec!r}: {exc}") from None
    if not callable(obj):
        raise ConfigError(f"plug-in {spec!r}: not callable")
    return obj


def stop_on_signals(stop: threading.Event) -> None:
    """SIGINT/SIGTERM set ``stop`` (the loops then finish cleanly)."""
    def handler(signum, frame):
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)


def _session(cfg: StudioConfig):
    from capture.session import load_session

    if cfg.session is None:
        raise ConfigError(f"{cfg.path}: studio.session: needed for replay cameras / calibration")
    return load_session(cfg.session)


def preflight(cfg: StudioConfig, host: str, *, fit_plugin: str | None = None) -> None:
    """What ``contourcap run`` checks before starting ``host``'s workers: the session (calibration,
    subject) that its tracker or replay cameras need loads, and every camera of the studio is calibrated.  ConfigError / SessionError /
    CalibrationError name the file; without this each worker would fail and be restarted forever."""
    replay = any(c.backend == "replay" for c in cfg.cameras_on(host))
    session = _session(cfg) if replay or (cfg.tracker_host == host and not fit_plugin) else None
    if cfg.tracker_host == host and not fit_plugin:
        from capture.calibration import load_calibration

        calibrated = ({c.name for c in load_calibration(cfg.calibration)} if cfg.calibration is not None
                      else {c.name for c in session.calibration})
        missing = [c.name for c in cfg.cameras if c.name not in calibrated]
        if missing:  # the tracker would report every frame as "unknown camera(s)"
            where = cfg.calibration or session.root / "calibration.toml"
            raise ConfigError(f"{where}: no calibration for camera(s) {missing} of {cfg.path} "
                              f"(calibrated: {sorted(calibrated)})")


def needs_trigger(cfg: StudioConfig, cameras) -> bool:
    """Whether these cameras take their frame ids from the USB trigger box."""
    return cfg.trigger.backend == "usb" and any(cfg.camera(c).backend == "opencv" for c in cameras)


def start_trigger(cfg: StudioConfig, stop: threading.Event, *, resync_s: float = 2.0, backend=None,
                  clock: Callable[[], int] | None = None):
    """Open the USB trigger box, run it at ``[trigger] fps`` and re-anchor its clock every ``resync_s``
    in a daemon thread (a trigger failure sets ``stop``).  ``backend``: a pyusb backend (tests)."""
    import time

    from capture.trigger import TriggerBox, TriggerError

    kw = {"clock": clock} if clock is not None else {}
    try:
        box = TriggerBox.find(backend=backend, **kw)
        box.set_rate(cfg.trigger.fps)
        box.start()
        time.sleep(2.0 / cfg.trigger.fps)
        box.refresh()
    except TriggerError as exc:
        raise ConfigError(f"{cfg.path}: trigger: {exc}") from None

    def resync() -> None:
        while not stop.wait(resync_s):
            try:
                box.refresh()
            except TriggerError as exc:
                log.error("trigger box lost: %s", exc)
                stop.set()
                return

    threading.Thread(target=resync, name="trigger-resync", daemon=True).start()
    return box


def free_run_frame_ids(fps: float) -> Callable[[int], int]:
    """Frame ids of cameras without a trigger box: the index of the nearest ``1/fps`` tick of the
    wall clock (``time.time_ns``, NTP/PTP-synchronised across hosts).  Frames of separately started
    (or restarted) camera processes then share ids when taken at about the same time; counting from
    0 per process instead misaligned the cameras and, after a restart, made every frame of the
    restarted camera "late" in live mode for good."""
    if not (fps > 0):
        raise ConfigError(f"fps must be positive to number frames, got {fps!r}")
    period_ns = int(round(1e9 / fps))
    return lambda timestamp_ns: (int(timestamp_ns) + period_ns // 2) // period_ns


class PreloadedReplay:
    """A replay camera decoded into memory when opened, then served from there (``fast`` pacing:
    an :class:`~service.workers.loops.EpochPacer` paces it), looping like ``ReplaySource(loop=True)``
    (ids and timestamps keep increasing by one clip per pass).  A stand-in for a camera that
    delivers decoded frames: decoding the session's videos is a cost of the replay, not of a studio
    (FFV1 800x600: ~26 ms a frame on one core, 6 cameras x 30 fps = 4.7 cores)."""

    def __init__(self, source, *, fps: float, loop: bool) -> None:
        self.name, self._source, self.fps, self.loop = source.name, source, float(fps), loop
        self._frames: list = []
        self._next = self._pass = 0

    def __enter__(self) -> "PreloadedReplay":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:
        from capture.sources import EndOfStream

        self._source.open()
        try:
            while True:
                try:
                    self._frames.append(self._source.read())
                except EndOfStream:
                    break
        finally:
            self._source.close()

    def read(self):
        from capture.sources import EndOfStream, Frame

        if self._next >= len(self._frames):
            if not self.loop or not self._frames:
                raise EndOfStream(f"preloaded replay camera {self.name!r}: end")
            self._next, self._pass = 0, self._pass + 1
        f, first, last = self._frames[self._next], self._frames[0], self._frames[-1]
        self._next += 1
        ids = (last.frame_id - first.frame_id + 1) * self._pass
        ns = (last.timestamp_ns - first.timestamp_ns + int(round(1e9 / self.fps))) * self._pass
        return Frame(f.camera, f.frame_id + ids, f.timestamp_ns + ns, f.image)

    def close(self) -> None:
        self._frames = []


def build_sources(cfg: StudioConfig, cameras: tuple[str, ...], *, mode: str, paced: bool = False,
                  frame_id_at: Callable[[int], int] | None = None, loop: bool = False,
                  preload: bool = False) -> dict:
    """Open camera sources: replay (realtime pacing live, as fast as credits allow lossless, or
    ``paced`` externally by an EpochPacer) or OpenCV (frame ids from ``frame_id_at``, the trigger
    box's, when given, else :func:`free_run_frame_ids` on wall-clock timestamps).  ``loop``: replays restart at the end with increasing frame ids.
    ``preload`` (benchmarks, paced replays only): replays are decoded into memory first (:class:`PreloadedReplay`)."""
    out: dict = {}
    try:
        for name in cameras:
            out[name] = _open_source(cfg, name, mode=mode, paced=paced, frame_id_at=frame_id_at, loop=loop,
                                     preload=preload)
    except BaseException:  # release the cameras already opened
        for src in out.values():
            src.close()
        raise
    return out


def _open_source(cfg: StudioConfig, name: str, *, mode: str, paced: bool, frame_id_at, loop: bool,
                 preload: bool = False):
    """One camera source, opened."""
    cam = cfg.camera(name)
    if cam.backend == "replay":
        from capture.replay import ReplaySource

        session = _session(cfg)
        if preload and paced:
            src = PreloadedReplay(ReplaySource(session, name, pacing="fast"), fps=session.fps, loop=loop)
        else:
            src = ReplaySource(session, name, pacing="realtime" if mode == "live" and not paced else "fast",
                               loop=loop)
    else:
        from capture.opencv_source import OpenCVSource

        import time

        device = int(cam.source) if cam.source.isdigit() else cam.source
        fps = cam.fps or cfg.trigger.fps
        clock = {} if frame_id_at is not None else {"clock": time.time_ns}  # the trigger box's clock is its own
        src = OpenCVSource(device, name=name, width=cam.width, height=cam.height, fps=fps, exposure=cam.exposure,
                           frame_id_at=frame_id_at if frame_id_at is not None else free_run_frame_ids(fps), **clock)
    src.open()
    return src


def build_segmenters(cfg: StudioConfig, cameras: tuple[str, ...], *, plugin: str | None = None) -> dict:
    """One segmenter per camera: a plug-in factory ``f(camera) -> Segmenter``, else
    :class:`~service.workers.components.BackgroundSegmenter` with the session's background model as
    ``service.offline`` builds it (replay) or learnt from the first frames (live cameras: the studio
    must be empty at start-up)."""
    if plugin:
        factory = load_plugin(plugin)
        return {c: factory(c) for c in cameras}
    from service.workers.components import BackgroundSegmenter

    replayed = [c for c in cameras if cfg.camera(c).backend == "replay"]
    models = {}
    if replayed:  # exactly the offline pipeline's models, so lossless replay gives the offline poses
        from service.offline import background_models

        models, _ = background_models(_session(cfg), replayed)
    return {c: BackgroundSegmenter(model=models.get(c)) for c in cameras}


def build_fitter(cfg: StudioConfig, *, plugin: str | None = None) -> Callable:
    """The tracker (``tracker.fitting.tracking.Tracker`` via :class:`~service.workers.components.TrackerFitter`) or a
    plug-in factory ``f(cfg) -> Fitter``."""
    if plugin:
        return load_plugin(plugin)(cfg)
    from service.workers.components import TrackerFitter

    session = _session(cfg)
    if cfg.calibration is not None:
        from capture.calibration import load_calibration

        session = replace(session, calibration=tuple(load_calibration(cfg.calibration)))
    return TrackerFitter.from_session(session, model=cfg.model)


def add_connection_args(parser) -> None:
    """``--config`` / ``--connect`` / ``--studio``: how a client (echo, view, ...) reaches a studio."""
    parser.add_argument("--config", default=None, help="studio TOML (its [zenoh] settings and studio name)")
    parser.add_argument("--connect", action="append", default=None,
                        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--studio", default=None, help="studio name (default: the config's, else 'default')")
    parser.add_argument("--timeout-s", type=float, default=5.0, help="how long to wait for a peer/router")


def client_settings(args) -> tuple[ZenohSettings, str]:
    """Zenoh settings and studio name of a client from :func:`add_connection_args` arguments."""
    from service.config import load_config

    studio = "default"
    if args.config:
        cfg = load_config(args.config)
        studio = cfg.studio
        settings = worker_settings(cfg, hub_endpoint(cfg) if cfg.zenoh.mode == "peer" else None)
    else:
        settings = ZenohSettings(connect=(DEFAULT_HUB,), listen=("tcp/127.0.0.1:0",))
    if args.connect:
        settings = replace(settings, connect=tuple(args.connect))
    settings = replace(settings, connect_timeout_s=float(args.timeout_s))
    return settings, args.studio or studio
