"""The camera-source interface every backend implements, its frame record and named errors.

A source is a context manager; ``read()`` returns the next ``Frame`` or
raises one of the errors below.  Backends: ``capture.replay.ReplaySource``
(session files), ``capture.opencv_source.OpenCVSource`` (UVC / V4L2 through
``cv2.VideoCapture``).  ``tests/capture/test_sources_contract.py`` runs one contract
suite against all of them.  The studio config's ``[[camera]]`` tables and the
factory that builds a backend from one are in ``capture.backends``.

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
