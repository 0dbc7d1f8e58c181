"""Camera backends by configuration: the ``[[camera]]`` spec of a studio config and the source factory.

``parse_source_specs`` validates the ``[[camera]]`` tables of ``studio.toml`` (the keys capture
needs) into :class:`SourceSpec` records; :func:`open_source` builds the backend for one spec:
``capture.replay.ReplaySource`` over the studio's session or ``capture.opencv_source.OpenCVSource``
on a device.  ``contourcap record`` and the service's camera worker both build their sources here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from capture.opencv_source import OpenCVSource
from capture.replay import ReplaySource
from capture.session import Session
from capture.sources import OpenError, SourceBase

__all__ = ["SPEC_KEYS", "SERVICE_KEYS", "BACKENDS", "SourceSpec", "parse_source_specs", "open_source"]

SPEC_KEYS = {"name", "backend", "source", "width", "height", "fps", "exposure", "host"}
SERVICE_KEYS = {"encoding"}  # [[camera]] keys only the service uses; ignored here
BACKENDS = ("opencv", "replay")


@dataclass(frozen=True)
class SourceSpec:
    """One ``[[camera]]`` table of a studio config, as far as capture is concerned.

    Attributes
    ----------
    name : str
        Camera name (required).
    backend : {"replay", "opencv"}
        ``"replay"`` (default) replays the studio's session; ``"opencv"`` opens a device.
    source : int or str
        opencv: device index (``0`` or ``"0"``), device path (``"/dev/video0"``) or video file;
        replay: ignored (the studio's session is used).
    width, height : int or None
        opencv: requested capture size (pixels).
    fps : float or None
        opencv: requested frame rate (frames per second).
    exposure : float or None
        opencv: requested exposure (driver units).
    host : str or None
        The capture host the camera is plugged into.
    """

    name: str
    backend: str = "replay"
    source: int | str = ""
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    exposure: float | None = None
    host: str | None = None


def parse_source_specs(tables, *, where: str = "<config>") -> tuple[SourceSpec, ...]:
    """Validate a studio config's ``[[camera]]`` list.

    Parameters
    ----------
    tables : list of dict
        The parsed ``[[camera]]`` tables; the service-only key ``encoding`` is ignored.
    where : str
        File name for the error messages.

    Returns
    -------
    tuple of SourceSpec
        One per table, in order; names are unique.

    Raises
    ------
    ValueError
        Naming ``where``, the table index and the key.
    """
    if not isinstance(tables, list) or not tables:
        raise ValueError(f"{where}: at least one [[camera]] table is needed")
    specs = [_spec(t, f"{where}: camera[{i}]") for i, t in enumerate(tables)]
    names = [s.name for s in specs]
    for i, n in enumerate(names):
        if n in names[:i]:
            raise ValueError(f"{where}: camera[{i}].name: {n!r} repeated (camera names must be unique)")
    return tuple(specs)


def _spec(t, at: str) -> SourceSpec:
    """One validated ``[[camera]]`` table; ``at`` prefixes the error messages."""
    if not isinstance(t, dict):
        raise ValueError(f"{at}: expected a table")
    unknown = set(t) - SPEC_KEYS - SERVICE_KEYS
    if unknown:
        raise ValueError(f"{at}: unknown key(s) {sorted(unknown)} (known: {sorted(SPEC_KEYS | SERVICE_KEYS)})")
    name = t.get("name")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{at}.name: missing (a non-empty string)")
    backend = t.get("backend", "replay")
    if backend not in BACKENDS:
        raise ValueError(f"{at}.backend: must be one of {BACKENDS}, got {backend!r}")
    source = t.get("source", "")
    if isinstance(source, bool) or not isinstance(source, (int, str)):
        raise ValueError(f"{at}.source: must be a device index or a path, got {source!r}")
    if isinstance(source, str) and source.strip().isdigit():
        source = int(source)
    if backend == "opencv" and source == "":
        raise ValueError(f"{at}.source: opencv cameras need a device index or path")
    opts = {}
    for key, kind in (("width", int), ("height", int), ("fps", float), ("exposure", float)):
        value = t.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float) if kind is float else int)):
            raise ValueError(f"{at}.{key}: must be a number, got {value!r}")
        if value is not None and key != "exposure" and value <= 0:
            raise ValueError(f"{at}.{key}: must be positive, got {value!r}")
        opts[key] = None if value is None else kind(value)
    host = t.get("host")
    if host is not None and (not isinstance(host, str) or not host):
        raise ValueError(f"{at}.host: must be a non-empty string, got {host!r}")
    return SourceSpec(name, backend, source, host=host, **opts)


def open_source(spec: SourceSpec, *, session: Session | None = None, clock: Callable[[], int] | None = None,
                frame_id_at: Callable[[int], int] | None = None, pacing: str = "fast", loop: bool = False,
                preload: bool = False, background: bool = False) -> SourceBase:
    """A (not yet opened) source for one camera.

    Parameters
    ----------
    spec : SourceSpec
        The camera.
    session : Session, optional
        The session a ``replay`` camera replays (required for those).
    clock : callable () -> int, optional
        Nanosecond clock for timestamps (realtime replay pacing, opencv software timestamps);
        default ``time.monotonic_ns``.
    frame_id_at : callable (timestamp_ns) -> int, optional
        opencv: maps a frame's timestamp to its frame id (a trigger box's ``frame_id_at``, or free-run
        wall-clock ticks); None counts frames from 0.
    pacing : {"fast", "realtime", "step"}
        replay pacing (see ``capture.replay``).
    loop : bool
        replay: restart at the end with increasing frame ids.
    preload : bool
        replay: decode the camera's footage into memory when opened.
    background : bool
        replay: the camera's background media (the empty room) instead of its footage; a live camera
        is the same stream either way.

    Returns
    -------
    ReplaySource or OpenCVSource
        Enter it (``with``) or call ``open()`` before reading; ``OpenError`` for a replay camera
        without a session.
    """
    clock = time.monotonic_ns if clock is None else clock
    if spec.backend == "replay":
        if session is None:
            raise OpenError(f"camera {spec.name!r}: backend 'replay' needs a session")
        return ReplaySource(session, spec.name, pacing=pacing, clock=clock, loop=loop, preload=preload,
                            background=background)
    return OpenCVSource(
        spec.source, name=spec.name, width=spec.width, height=spec.height, fps=spec.fps,
        exposure=spec.exposure, clock=clock, frame_id_at=frame_id_at,
    )
