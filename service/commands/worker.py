"""``contourcap worker camera|segment|track``: one worker process (usually started by ``contourcap run``)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import socket
import sys
import threading
import time

HELP = "run one worker process (camera, segment or track) of a studio"
PRELOAD_ENV = "CONTOURCAP_PRELOAD_REPLAY"
LINGER_S = 0.5
"""Seconds a worker keeps its zenoh session open after its loop returned, before closing it: a session
closed right after a put loses what a slow reader has not read yet (a track worker's last pose and
credit after ``--max-frames``, every worker's 'finished' status), and zenoh cannot tell when matched
subscribers got a put.  Bounded: at most this long per exit, only after a worker ran to its end."""


def add_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("role", choices=("camera", "segment", "track"), help="which worker")
    parser.add_argument("--config", required=True, help="studio TOML (see deploy/studio.example.toml)")
    parser.add_argument("--cameras", default=None,
                        help="comma-separated camera names (default: this host's cameras; track: all)")
    parser.add_argument("--host", default=None, help="host name in the config (default: this machine's)")
    parser.add_argument("--hub", default=None,
                        help="peer mode: the supervisor's hub endpoint to connect to (set by `contourcap run`)")
    parser.add_argument("--plugin", default=None,
                        help="module:factory replacing the segmenter (f(camera)) or the fitter (f(config))")
    parser.add_argument("--idle-exit-s", type=float, default=None,
                        help="segment/track: exit 0 after this long without input (replays)")
    parser.add_argument("--max-frames", type=int, default=None, help="track: exit after this many poses")
    parser.add_argument("--epoch-ns", type=int, default=None,
                        help="camera, live replay: wall-clock ns at which session time 0 is due (set by run)")
    parser.add_argument("--loop", action="store_true", help="camera, replay: loop the session forever")
    parser.add_argument("--preload", action="store_true", default=os.environ.get(PRELOAD_ENV) == "1",
                        help="camera, live replay: decode the session into memory first and serve it from there "
                             f"(benchmarks: a camera delivering decoded frames; default from ${PRELOAD_ENV}=1)")
    parser.add_argument("--log-level", default="INFO", type=str.upper,
                        choices=("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL"))


def _setup_errors() -> tuple[type[BaseException], ...]:
    """What bad configuration, files or devices raise while a worker is being built: one line, exit 2."""
    from capture.calibration import CalibrationError
    from capture.session import SessionError
    from capture.sources import SourceError
    from capture.trigger import TriggerError
    from service.config import ConfigError
    from tracker.body.model import ModelError

    return (ConfigError, SessionError, CalibrationError, SourceError, TriggerError, ModelError)


def run(args: argparse.Namespace) -> int:
    import cv2

    from service.wire.bus import BusError, Keys, open_session
    from service.config import ConfigError, load_config
    from service.workers.runtime import (build_fitter, build_segmenters, build_sources, needs_trigger, start_trigger,
                                 stop_on_signals, worker_settings)

    logging.basicConfig(level=args.log_level, stream=sys.stderr,
                        format=f"%(asctime)s {args.role} %(levelname)s %(message)s")
    log = logging.getLogger("contourcap.worker")
    cv2.setNumThreads(1)
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        cfg = load_config(args.config)
        host = args.host or socket.gethostname()
        if args.cameras:
            cams = tuple(c.strip() for c in args.cameras.split(",") if c.strip())
            for c in cams:
                cfg.camera(c)
        elif args.role == "track":
            cams = tuple(c.name for c in cfg.cameras)
        else:
            cams = tuple(c.name for c in cfg.cameras_on(host))
            if not cams:
                raise ConfigError(f"{cfg.path}: no camera on host {host!r} (hosts: {list(cfg.hosts)}); "
                                  "pass --host or --cameras")
        session = open_session(worker_settings(cfg, args.hub))
    except (ConfigError, BusError) as exc:
        print(f"contourcap worker {args.role}: {exc}", file=sys.stderr)
        return 2
    keys = Keys(cfg.studio)
    component = "track" if args.role == "track" else f"{args.role}-{'-'.join(cams) if args.cameras else host}"
    from service.workers.base import WorkerError

    finished = False
    fitter = None
    try:
        if args.role == "camera":
            from service.workers.camera import EpochPacer, run_camera_worker

            paced = args.epoch_ns is not None and cfg.delivery == "live"
            box = start_trigger(cfg, stop) if needs_trigger(cfg, cams) else None
            sources = build_sources(cfg, cams, mode=cfg.delivery, paced=paced, loop=args.loop,
                                    frame_id_at=None if box is None else box.frame_id_at, preload=args.preload)
            try:
                stats = run_camera_worker(session, keys, sources, mode=cfg.delivery, stop=stop,
                                          encodings={c: cfg.camera(c).encoding for c in cams},
                                          jpeg_quality=cfg.jpeg_quality, window=cfg.window, component=component,
                                          pace=EpochPacer(args.epoch_ns) if paced else None)
            finally:
                for src in sources.values():
                    src.close()
                if box is not None:
                    box.stop()
                    box.close()
        elif args.role == "segment":
            from service.workers.segment import run_segment_worker

            stats = run_segment_worker(session, keys, build_segmenters(cfg, cams, plugin=args.plugin),
                                       mode=cfg.delivery, stop=stop, component=component,
                                       idle_exit_s=args.idle_exit_s)
        else:
            from service.workers.track import run_track_worker

            if cfg.method == "blobs" and not args.plugin:  # frames in, no segment workers (blob_track docstring)
                from service.workers.blob_track import run_blob_track_worker as run_track_worker
            fitter = build_fitter(cfg, plugin=args.plugin)
            idle = None if args.idle_exit_s is None else args.idle_exit_s
            stats = run_track_worker(session, keys, cams, fitter, mode=cfg.delivery,
                                     set_timeout_s=cfg.set_timeout_ms / 1e3, stop=stop,
                                     max_frames=args.max_frames, idle_exit_s=idle)
        finished = True
        log.info("finished: %s", json.dumps(stats, sort_keys=True, default=str))  # one JSON object: machine-readable
        return 0
    except _setup_errors() as exc:
        print(f"contourcap worker {args.role}: {exc}", file=sys.stderr)
        return 2
    except WorkerError as exc:  # non-zero: the supervisor restarts this worker
        print(f"contourcap worker {args.role}: {exc}", file=sys.stderr)
        return 1
    finally:
        if finished:
            time.sleep(LINGER_S)  # its last messages reach slow readers (see LINGER_S)
        session.close()
        _leave_running_calibration(fitter, 0 if finished else 1, log)


def _leave_running_calibration(fitter, code: int, log: logging.Logger) -> None:
    """End the process now, with ``code``, when ``fitter``'s automatic subject calibration
    (``service.workers.auto_subject``) still runs: that thread cannot be interrupted, and the
    interpreter's exit would stop it inside compiled code and abort the process."""
    auto = getattr(fitter, "auto_subject", None)
    if auto is None or not auto.running:
        return
    log.info("automatic subject calibration still running: dropped at exit")
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def main(argv: list[str] | None = None) -> int:
    """``python -m service.commands.worker ROLE ...``: the same command without loading every other
    sub-command (fast start-up, used by the supervisor)."""
    parser = argparse.ArgumentParser(prog="contourcap worker", description=HELP)
    add_args(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    from service.blas import pin_blas_threads

    pin_blas_threads()
    sys.exit(main())
