"""Where workers and clients connect: the hub endpoint, a worker's zenoh settings, client options.

Single-host peer mode: the supervisor opens a *hub* session listening on ``[zenoh] listen``
(default ``tcp/127.0.0.1:7447``); each worker is a peer that connects to the hub and listens on an
ephemeral loopback port, so gossip scouting meshes the workers with each other (multicast off).
Multi-host: ``mode = "client"`` and ``connect`` to ``contourcap router``; the workers use
``[zenoh]`` as written.
"""

from __future__ import annotations

from dataclasses import replace

from service.config import StudioConfig, load_config
from service.wire.bus import ZenohSettings

__all__ = ["DEFAULT_HUB", "hub_endpoint", "worker_settings", "add_connection_args", "client_settings"]

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
    """Zenoh settings of a worker: a loopback peer of ``hub``, or ``[zenoh]`` as written (``hub`` None)."""
    if hub is None:
        return cfg.zenoh
    return replace(cfg.zenoh, mode="peer", connect=(hub,), listen=("tcp/127.0.0.1:0",), config_file=None)


def add_connection_args(parser) -> None:
    """``--config`` / ``--connect`` / ``--studio`` / ``--timeout-s``: how a client (echo, view, ...) reaches a studio."""
    parser.add_argument("--config", default=None, help="studio TOML (its [zenoh] settings and studio name)")
    parser.add_argument("--connect", action="append", default=None,
                        help="zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--studio", default=None, help="studio name (default: the config's, else 'default')")
    parser.add_argument("--timeout-s", type=float, default=5.0, help="how long to wait for a peer/router")


def client_settings(args) -> tuple[ZenohSettings, str]:
    """Zenoh settings and studio name of a client from :func:`add_connection_args` arguments."""
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
