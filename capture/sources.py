"""The camera-source interface every backend implements, its frame record and named errors.

A source is a context manager; ``read()`` returns the next ``Frame`` or
raises one of the errors below.  Backends: ``capture.replay.ReplaySource``
(session files), ``capture.opencv_source.OpenCVSource`` (UVC / V4L2 through
``cv2.VideoCapture``).  ``tests/test_sources_contract.py`` runs one contract
suite against all of them.  ``SourceSpec`` / ``parse_source_specs`` read a
studio config's ``[[camera]]`` tables and ``open_source`` builds the backend.

Errors (after pupil's ``InitialisationError`` / ``StreamError`` /
``EndofVideoError``)::

    SourceError          base class; also "read() on a source that is not open"
    ├── OpenError        the device / file could not be opened (message names it)
    ├── StreamLostError  a live stream stopped delivering (unplugged, driver error)
    ├── SourceTimeout    no frame within the requested time (step pacing, live read timeout)
    └── EndOfStream      a finite source has no more frames; every later read() raises it again
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from capture.errors import CaptureError


__all__ = [
    "Frame",
    "Source",
    "SourceError",
    "OpenError",
    "StreamLostError",
    "SourceTimeout",
    "EndOfStream",
    "SourceBase",
    "SourceSpec",
    "parse_source_specs",
    "open_source",
]


class SourceError(CaptureError):
    """Base class of camera-source errors."""


class OpenError(SourceError):
    """A camera device or media file could not be opened."""


class StreamLostError(SourceError):
    """A stream that was delivering frames stopped (device unplugged, read failure)."""


class SourceTimeout(SourceError):
    """No frame became available within the allowed time."""


class EndOfStream(SourceError):
    """A finite source (file, session) has delivered its last frame."""


@dataclass(frozen=True, eq=False)
class Frame:
    """One image of one camera.

    Attributes
    ----------
    camera : str
        Camera name (as in the session / calibration).
    frame_id : int
        Trigger pulse number; frames of different cameras with the same id
        were exposed together.
    timestamp_ns : int
        Capture time in nanoseconds (session time for replay, injected clock
        for live sources).
    image : ndarray, shape (h, w, 3), uint8, BGR
    """

    camera: str
    frame_id: int
    timestamp_ns: int
    image: np.ndarray


@runtime_checkable
class Source(Protocol):
    """What the capture worker, the recorder and the tests rely on."""

    name: str

    def __enter__(self) -> "Source": ...

    def __exit__(self, *exc) -> None: ...

    def read(self) -> Frame:
        """The next frame; raises ``EndOfStream``, ``StreamLostError``, ``SourceTimeout`` or ``SourceError``."""
        ...


class SourceBase:
    """Context-manager plumbing shared by the backends: ``with src:`` = ``open()`` … ``close()``."""

    name: str

    def __enter__(self):
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> None:  # pragma: no cover - every backend overrides
        raise NotImplementedError

    def close(self) -> None:  # pragma: no cover - every backend overrides
        raise NotImplementedError


SPEC_KEYS = {"name", "backend", "source", "width", "height", "fps", "exposure", "host"}
SERVICE_KEYS = {"encoding"}  # [[camera]] keys only the service uses; ignored here
BACKENDS = ("opencv", "replay")


@dataclass(frozen=True)
class SourceSpec:
    """One ``[[camera]]`` table of a studio config, as far as capture is concerned.

    Keys: ``name`` (required), ``backend = "opencv" | "replay"`` (default
    ``"replay"``), ``source`` (opencv: device index ``0`` / ``"0"``, device
    path ``"/dev/video0"`` or video file; replay: ignored, the studio's
    session is used), and for opencv the optional requests ``width``,
    ``height``, ``fps``, ``exposure``; ``host`` (optional) names the capture
    host the camera is plugged into.  ``encoding`` belongs to the service and
    is ignored.
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
    """Validate a studio config's ``[[camera]]`` list; ``ValueError`` names ``where`` and the key."""
    if not isinstance(tables, list) or not tables:
        raise ValueError(f"{where}: at least one [[camera]] table is needed")
    specs = []
    for i, t in enumerate(tables):
        at = f"{where}: camera[{i}]"
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
        specs.append(SourceSpec(name, backend, source, host=host, **opts))
    names = [s.name for s in specs]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"{where}: camera names must be unique, repeated: {dup}")
    return tuple(specs)


def open_source(spec: SourceSpec, *, session=None, clock=None, frame_id_at=None, pacing: str = "fast"):
    """A (not yet opened) source for ``spec``: ``ReplaySource`` over ``session`` or ``OpenCVSource``."""
    import time

    clock = time.monotonic_ns if clock is None else clock
    if spec.backend == "replay":
        from capture.replay import ReplaySource

        if session is None:
            raise OpenError(f"camera {spec.name!r}: backend 'replay' needs a session")
        return ReplaySource(session, spec.name, pacing=pacing, clock=clock)
    from capture.opencv_source import OpenCVSource

    return OpenCVSource(
        spec.source, name=spec.name, width=spec.width, height=spec.height, fps=spec.fps,
        exposure=spec.exposure, clock=clock, frame_id_at=frame_id_at,
    )
