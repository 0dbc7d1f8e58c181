"""How a studio config builds a worker: one import path for the concern modules below.

- :mod:`~service.workers.topology`: hub endpoint, a worker's zenoh settings, client options
- :mod:`~service.workers.plugins`: plug-ins, segmenters, fitter
- :mod:`~service.workers.signals`: SIGINT/SIGTERM
- :mod:`~service.workers.preflight`: checks before ``contourcap run`` starts a host
- :mod:`~service.workers.trigger`: the USB trigger box
- :mod:`~service.workers.frame_ids`: frame ids without a trigger box
- :mod:`~service.workers.sources`: the camera sources
"""

from __future__ import annotations

from service.workers.frame_ids import free_run_frame_ids
from service.workers.plugins import build_fitter, build_segmenters, load_plugin
from service.workers.preflight import preflight
from service.workers.signals import stop_on_signals
from service.workers.sources import build_sources, open_camera
from service.workers.topology import DEFAULT_HUB, add_connection_args, client_settings, hub_endpoint, worker_settings
from service.workers.trigger import needs_trigger, start_trigger

__all__ = [
    "DEFAULT_HUB", "hub_endpoint", "worker_settings", "add_connection_args", "client_settings", "load_plugin",
    "build_segmenters", "build_fitter", "stop_on_signals", "preflight", "needs_trigger", "start_trigger",
    "free_run_frame_ids", "build_sources", "open_camera",
]  # fmt: skip
