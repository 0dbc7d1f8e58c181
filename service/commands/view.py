"""``contourcap view``: bridge a live studio to the rerun viewer (spawned, web, or saved to .rrd)."""

from __future__ import annotations

import argparse
import sys
import threading
import time

HELP = "show a live studio in rerun: camera frusta, images, silhouettes, 3-D skeleton, coloured hull, metrics"


def add_args(parser: argparse.ArgumentParser) -> None:
    from service.workers.runtime import add_connection_args

    add_connection_args(parser)
    sink = parser.add_mutually_exclusive_group()
    sink.add_argument("--save", default=None, help="write a .rrd file instead of showing a viewer")
    sink.add_argument("--serve-web", action="store_true", help="serve a web viewer (http://127.0.0.1:PORT)")
    parser.add_argument("--web-port", type=int, default=9090)
    parser.add_argument("--grpc-port", type=int, default=9876)
    parser.add_argument("--calibration", default=None, help="calibration TOML for the camera frusta "
                        "(default: the config's)")
    parser.add_argument("--image-every", type=int, default=5, help="log every N-th frame's images")
    parser.add_argument("--no-images", action="store_true", help="skip camera images and silhouettes")
    parser.add_argument("--count", type=int, default=None, help="exit after this many poses")
    parser.add_argument("--duration-s", type=float, default=None, help="exit after this long")
    parser.add_argument("--idle-exit-s", type=float, default=None, help="exit after this long without data")


def _calibration_path(args):
    if args.calibration or not args.config:
        return args.calibration
    from service.config import load_config

    cfg = load_config(args.config)
    if cfg.calibration is not None:
        return cfg.calibration
    return None if cfg.session is None else cfg.session / "calibration.toml"


def run(args: argparse.Namespace) -> int:
    import rerun as rr

    from service.wire.bus import BusError, Inbox, Keys, open_session
    from service.config import ConfigError
    from service.wire.messages import ChamferMessage, FrameMessage, MessageError
    from service.wire.hull import HullMessage
    from service.wire.records import PoseRecord
    from service.workers.runtime import client_settings, stop_on_signals
    from service.viewer import RerunBridge, cameras_for_view

    stop = threading.Event()
    stop_on_signals(stop)
    try:
        settings, studio = client_settings(args)
        calib = _calibration_path(args)
        cameras = cameras_for_view(calib) if calib is not None else []
        # the rerun sink first: a bad --save path or busy port must not leave a zenoh session open
        rec = rr.RecordingStream("contourcap", recording_id=f"contourcap-{studio}")
        if args.save:
            try:
                rec.save(args.save)
            except RuntimeError as exc:
                raise MessageError(f"--save {args.save}: {exc}") from None
        elif args.serve_web:
            uri = rec.serve_grpc(grpc_port=args.grpc_port)
            rr.serve_web_viewer(web_port=args.web_port, open_browser=False, connect_to=uri)
            print(f"contourcap view: web viewer at http://127.0.0.1:{args.web_port}/?url={uri}", file=sys.stderr)
        else:
            rec.spawn()
        session = open_session(settings)
    except (ConfigError, BusError, MessageError) as exc:
        print(f"contourcap view: {exc}", file=sys.stderr)
        return 2
    bridge = RerunBridge(rec, cameras=cameras, image_every=args.image_every)
    keys = Keys(studio)
    inboxes: list = []
    start = last = time.monotonic()
    try:
        inboxes.append((Inbox(session, keys.pose, PoseRecord.from_bytes, mode="live", depth=64), bridge.on_pose))
        inboxes.append((Inbox(session, keys.hull, HullMessage.from_bytes, mode="live", depth=2), bridge.on_hull))
        if not args.no_images:
            n = max(1, len(cameras))
            inboxes += [(Inbox(session, keys.frame("*"), FrameMessage.from_bytes, mode="live", depth=2 * n),
                         bridge.on_frame),
                        (Inbox(session, keys.chamfer("*"), ChamferMessage.from_bytes, mode="live", depth=2 * n),
                         bridge.on_chamfer)]
        while not stop.is_set():
            got_any = False
            for inbox, handle in inboxes:
                for item in inbox.drain():
                    got_any = True
                    handle(item.message)
            now = time.monotonic()
            last = now if got_any else last
            if ((args.count is not None and bridge.logged["poses"] >= args.count)
                    or (args.duration_s is not None and now - start > args.duration_s)
                    or (args.idle_exit_s is not None and now - last > args.idle_exit_s)):
                break
            stop.wait(0.02)
    finally:
        for inbox, _ in inboxes:
            inbox.close()
        session.close()
        rec.flush()
        if args.save:
            rec.disconnect()
    print(f"contourcap view: logged {bridge.logged}", file=sys.stderr)
    return 0
