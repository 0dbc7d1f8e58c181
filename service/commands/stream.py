"""``contourcap stream vmc|ws``: bridges from the studio's pose key (or a recorded take) to the VMC
protocol (Unity, Unreal, Blender, VTubing apps) and to WebSocket clients with a browser page."""

from __future__ import annotations

import argparse
import sys
import threading

from service.commands.argtypes import positive_float

HELP = "stream poses live (or replay a take) to VMC (OSC/UDP) or WebSocket clients and a browser page"

SMOOTH_HELP = ("1-euro smoothing of joints and pose parameters for the consumer: off, one-euro (MIN_CUTOFF 1.0 Hz, "
               "BETA 10) or one-euro:MIN_CUTOFF,BETA; a not-ok pose resets it")


def _source_args(p: argparse.ArgumentParser, smooth_default: str) -> None:
    from service.workers.runtime import add_connection_args

    add_connection_args(p)
    p.add_argument("--replay", default=None, metavar="POSES.jsonl",
                   help="stream this recorded take instead of the studio's live poses")
    p.add_argument("--rate", type=float, default=1.0, help="replay speed (1.0 = the take's real time)")
    p.add_argument("--loop", action="store_true", help="replay the take over and over")
    p.add_argument("--fps", type=positive_float, default=None, help="the take's frame rate (default: from its timestamps)")
    p.add_argument("--count", type=int, default=None, help="stop after this many poses (live or replay)")
    p.add_argument("--smooth", default=smooth_default, metavar="off|one-euro[:MIN_CUTOFF,BETA]",
                   help=f"{SMOOTH_HELP} (default {smooth_default})")


def add_args(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="bridge", metavar="vmc|ws")
    sub.required = True
    vmc = sub.add_parser("vmc", help="send poses as VMC (Performer -> Marionette, OSC over UDP)",
                         description="Send poses to a VMC Marionette: Unity humanoid bones, local rotations in "
                                     "Unity's left-handed Y-up frame (tracker (x, y, z) -> Unity (-y, z, x)), "
                                     "Hips at the pelvis; a not-ok pose sends no bones and /VMC/Ext/OK tracking 0.")
    vmc.add_argument("--to", required=True, metavar="HOST:PORT", help="the Marionette (VMC's usual port: 39539)")
    vmc.add_argument("--model", default=None, help="body model (default: the records' 'model')")
    vmc.add_argument("--height-m", type=float, default=None, help="subject height (bone offsets only)")
    vmc.add_argument("--session", default=None, help="take height/segment lengths from this session")
    _source_args(vmc, "one-euro")
    ws = sub.add_parser("ws", help="serve poses over WebSocket, and a page drawing the skeleton at /",
                        description="A WebSocket server sending each pose record as JSON text to every client "
                                    "(a slow client's oldest queued poses are dropped) and a browser page at "
                                    "http://HOST:PORT/.  A replay starts when the first client connects.")
    ws.add_argument("--host", default="127.0.0.1", help="address to listen on (0.0.0.0: every interface)")
    ws.add_argument("--port", type=int, default=8765, help="port for the page and the WebSocket (0: any free)")
    ws.add_argument("--queue", type=int, default=64, help="poses queued per client before dropping its oldest")
    _source_args(ws, "off")


class _Source:
    """Pose records with their take time, from a file (paced) or the studio's pose key (live)."""

    def __init__(self, args, stop: threading.Event) -> None:
        self.args, self.stop = args, stop
        self.records = None
        self.fps = args.fps
        if args.replay:
            from service.export import read_pose_records
            from service.outputs.timeline import make_timeline

            self.records = read_pose_records(args.replay)
            self.fps = make_timeline(self.records, fps=args.fps, where=args.replay).fps
            if not (args.rate > 0):
                raise ValueError(f"--rate must be positive, got {args.rate}")
        self.model_name = next((r.get("model") for r in self.records or () if r.get("model")), None)

    def __iter__(self):
        if self.records is not None:
            from service.outputs.replay import iter_replay

            for n, item in enumerate(iter_replay(self.records, self.fps, rate=self.args.rate, loop=self.args.loop,
                                                 stop=self.stop)):
                if self.args.count is not None and n >= self.args.count:
                    return
                yield item
            return
        from service.wire.bus import Inbox, Keys, open_session
        from service.wire.records import PoseRecord
        from service.workers.runtime import client_settings

        settings, studio = client_settings(self.args)
        session = open_session(settings)
        inbox = Inbox(session, Keys(studio).pose, PoseRecord.from_bytes, mode="live", depth=256)
        first_ts, n = None, 0
        try:
            while not self.stop.is_set() and (self.args.count is None or n < self.args.count):
                got = inbox.recv(0.1)
                if got is None:
                    continue
                rec = got.message
                first_ts = rec.timestamp_ns if first_ts is None else first_ts
                n += 1
                yield rec, (rec.timestamp_ns - first_ts) / 1e9
        finally:
            inbox.close()
            session.close()


def _smoother(args, fps):
    from service.outputs.smoothing import RecordSmoother
    from tracker.body.filters import parse_one_euro

    spec = parse_one_euro(args.smooth)
    return None if spec is None else RecordSmoother(*spec, None if args.replay is None else fps)


def run(args: argparse.Namespace) -> int:
    from service.wire.bus import BusError
    from service.config import ConfigError
    from service.export import ExportError
    from service.workers.runtime import stop_on_signals

    stop = threading.Event()
    stop_on_signals(stop)
    try:
        source = _Source(args, stop)
        smoother = _smoother(args, source.fps)
        if args.bridge == "vmc":
            return _run_vmc(args, source, smoother)
        return _run_ws(args, source, smoother, stop)
    except (ExportError, ConfigError, BusError, ValueError, RuntimeError) as exc:
        print(f"contourcap stream {args.bridge}: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--to: expected HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


def _run_vmc(args, source, smoother) -> int:
    from service.commands.export import model_for_export
    from service.outputs.vmc import VmcSender, run_bridge

    host, port = _host_port(args.to)

    def sender_for(rec):
        args.model = args.model or rec.get("model") or source.model_name
        sender = VmcSender(host, port, model_for_export(args, [rec]))
        print(f"streaming VMC to {host}:{port} (model {sender.frames.model.name}, smoothing {args.smooth})",
              flush=True)
        return sender

    try:
        sender = run_bridge(source, sender_for, smoother=smoother)
    except OSError as exc:
        raise RuntimeError(f"--to {args.to}: {exc}") from None
    if sender is not None:
        print(f"sent {sender.sent} poses ({sender.lost} not ok: /VMC/Ext/OK tracking 0) to {host}:{port}")
    return 0


def _run_ws(args, source, smoother, stop: threading.Event) -> int:
    import json

    from service.outputs.ws import run_bridge

    def texts():
        for rec, _ in source:
            text = rec.to_bytes().decode()
            joints = smoother.update(rec)[0] if smoother is not None else None
            if joints is not None:  # the record stays raw; the smoothed joints ride along
                obj = json.loads(text)
                obj["joints_smoothed"] = joints
                text = json.dumps(obj, separators=(",", ":"))
            yield text

    def on_ready(port: int) -> None:
        print(f"serving the page at http://{args.host}:{port}/ and poses at ws://{args.host}:{port}/"
              + (" (the replay starts when the first client connects)" if args.replay else ""), flush=True)

    try:
        hub = run_bridge(texts(), host=args.host, port=args.port, stop=stop, queue_size=args.queue,
                         wait_for_client=bool(args.replay), on_ready=on_ready)
    except OSError as exc:
        raise RuntimeError(f"--host/--port: cannot listen on {args.host}:{args.port} ({exc.strerror or exc})") from None
    print(f"sent {hub.sent} poses to WebSocket clients ({hub.dropped} dropped for slow clients)")
    return 0
