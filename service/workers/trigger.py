"""The USB trigger box of a camera worker: whether it needs one, and starting it."""

from __future__ import annotations

import logging
import threading
from typing import TYPE_CHECKING, Callable

from service.config import ConfigError, StudioConfig

if TYPE_CHECKING:
    from capture.trigger import TriggerBox

__all__ = ["needs_trigger", "start_trigger"]

log = logging.getLogger("contourcap.runtime")


def needs_trigger(cfg: StudioConfig, cameras) -> bool:
    """Whether these cameras (names) take their frame ids from the USB trigger box."""
    return cfg.trigger.backend == "usb" and any(cfg.camera(c).backend == "opencv" for c in cameras)


def start_trigger(cfg: StudioConfig, stop: threading.Event, *, resync_s: float = 2.0, backend=None,
                  clock: Callable[[], int] | None = None) -> TriggerBox:
    """The running trigger box at ``[trigger] fps`` (``capture.trigger.start_trigger_box``).

    Parameters
    ----------
    cfg : StudioConfig
    stop : threading.Event
        Set when the box is lost later (the camera worker then ends and is restarted).
    resync_s : float
        Seconds between re-anchorings of the box's clock.
    backend : pyusb backend, optional
        For tests.
    clock : callable () -> int, optional
        Host nanosecond clock.

    Raises
    ------
    ConfigError
        The box is absent or failed to start (it is released).
    """
    from capture.trigger import TriggerError, start_trigger_box  # pyusb: only where a box is used

    try:
        return start_trigger_box(cfg.trigger.fps, stop=stop, resync_s=resync_s, backend=backend, clock=clock,
                                 on_lost=lambda exc: log.error("trigger box lost: %s", exc))
    except TriggerError as exc:
        raise ConfigError(f"{cfg.path}: trigger: {exc}") from None
