"""UVC / V4L2 cameras (and video files) through ``cv2.VideoCapture``.

Real devices::

    from capture.opencv_source import OpenCVSource
    with OpenCVSource(0, name="cam0", width=1280, height=720, fps=30, exposure=-6) as src:
        frame = src.read()

``device`` is a device index (``0``), a device path (``"/dev/video2"``; a
stable ``/dev/v4l/by-id/…`` link is best in a studio where USB enumeration
order changes) or a video file path.  ``api_preference`` picks the backend
(``cv2.CAP_V4L2`` on Linux, ``cv2.CAP_DSHOW`` / ``cv2.CAP_MSMF`` on Windows,
``cv2.CAP_AVFOUNDATION`` on macOS).  Resolution, fps and exposure are
*requested*; drivers round or refuse them, so ``applied`` reports what the
driver says after opening (exposure units are driver-specific: V4L2 takes
absolute units of 100 µs with ``CAP_PROP_AUTO_EXPOSURE = 1`` (manual); set
``exposure=None`` to keep auto exposure).  Many UVC cameras queue a few
frames; ``buffer_size=1`` asks the driver to keep only the newest.

Timestamps are software timestamps: the injected ``clock`` (nanoseconds)
read right after each frame arrives.  Frame ids count frames from 0 per
open, or come from ``frame_id_at(timestamp_ns)`` (e.g. a trigger box's
``frame_id_at``; pass a ``latency_ns`` there so frames fall mid-period).  A
frame mapped to a pulse that already has a frame is skipped and counted in
``skipped`` (a constant +1 offset would otherwise follow), so ids stay
strictly increasing.

A live device that stops delivering raises ``StreamLostError``; a video file
that ends raises ``EndOfStream``.  No camera is attached on the CI machine:
tests run this class on video files (``tests/test_sources_contract.py``).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import cv2

from capture.sources import EndOfStream, Frame, OpenError, SourceBase, SourceError, StreamLostError

__all__ = ["OpenCVSource"]


class OpenCVSource(SourceBase):
    """A camera source over ``cv2.VideoCapture`` (see module docstring).

    Parameters
    ----------
    device : int or str
        Device index, device path or video file path.
    name : str
        Camera name stamped on frames.
    width, height, fps, exposure : optional requested capture settings.
    clock : callable () -> int
        Nanosecond clock for software timestamps.
    frame_id_at : callable (timestamp_ns) -> int, optional
        Maps a frame's timestamp to its trigger-pulse id.
    api_preference : int
        ``cv2.CAP_*`` backend.
    buffer_size : int, optional
        ``CAP_PROP_BUFFERSIZE`` request for live devices.
    """

    def __init__(
        self,
        device: int | str,
        *,
        name: str,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        exposure: float | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
        frame_id_at: Callable[[int], int] | None = None,
        api_preference: int = cv2.CAP_ANY,
        buffer_size: int | None = None,
    ):
        if not name:
            raise ValueError("OpenCVSource: 'name' must be non-empty")
        if isinstance(device, bool) or not isinstance(device, (int, str)):
            raise ValueError(f"camera {name!r}: device must be an index or a path, got {device!r}")
        self.device = device
        self.name = name
        self.requested = {"width": width, "height": height, "fps": fps, "exposure": exposure, "buffer_size": buffer_size}
        self.applied: dict[str, float] = {}
        self._clock = clock
        self._frame_id_at = frame_id_at
        self._api = api_preference
        self._cap = None
        self._next_id = 0
        self._ended = False
        self.skipped = 0
        self.is_file = isinstance(device, str) and not device.startswith("/dev/")

    def open(self) -> None:
        """Open the device or file; raises ``OpenError`` naming it."""
        self.close()
        where = f"camera {self.name!r} ({self.device})"
        if self.is_file and not Path(self.device).is_file():
            raise OpenError(f"{where}: file {self.device} not found")
        cap = cv2.VideoCapture(self.device, self._api)
        if not cap.isOpened():
            cap.release()
            raise OpenError(f"{where}: cv2.VideoCapture cannot open it (device busy, absent or unsupported)")
        if not self.is_file:
            self._configure(cap)
        self.applied = {
            "width": cap.get(cv2.CAP_PROP_FRAME_WIDTH),
            "height": cap.get(cv2.CAP_PROP_FRAME_HEIGHT),
            "fps": cap.get(cv2.CAP_PROP_FPS),
            "exposure": cap.get(cv2.CAP_PROP_EXPOSURE),
        }
        want = (self.requested["width"], self.requested["height"])
        got = (int(self.applied["width"]), int(self.applied["height"]))
        if any(w is not None and int(w) != g for w, g in zip(want, got)):
            cap.release()
            raise OpenError(f"{where}: asked for {want[0]}x{want[1]} but it delivers {got[0]}x{got[1]}; use a mode "
                            "the camera supports (its calibration must be of the same size)")
        self._cap = cap
        self._next_id = 0
        self._ended = False

    def _configure(self, cap) -> None:
        req = self.requested
        if req["buffer_size"] is not None:
            cap.set(cv2.CAP_PROP_BUFFERSIZE, req["buffer_size"])
        if req["width"] is not None:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, req["width"])
        if req["height"] is not None:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, req["height"])
        if req["fps"] is not None:
            cap.set(cv2.CAP_PROP_FPS, req["fps"])
        if req["exposure"] is not None:
            cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2 manual mode; other backends ignore it
            cap.set(cv2.CAP_PROP_EXPOSURE, req["exposure"])

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def read(self) -> Frame:
        if self._cap is None:
            raise SourceError(f"camera {self.name!r}: read() on a source that is not open")
        if self._ended:
            raise EndOfStream(f"camera {self.name!r}: end of {self.device}")
        while True:
            ok, image = self._cap.read()
            timestamp_ns = int(self._clock())
            if not ok or image is None:
                if self.is_file:
                    self._ended = True
                    raise EndOfStream(f"camera {self.name!r}: end of {self.device}")
                raise StreamLostError(f"camera {self.name!r} ({self.device}): no frame from the device (unplugged or driver error)")
            fid = self._next_id
            if self._frame_id_at is not None:
                fid = int(self._frame_id_at(timestamp_ns))
                if fid < self._next_id:  # its pulse already has a frame: timing ambiguous, skip it
                    self.skipped += 1
                    continue
            break
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        self._next_id = fid + 1
        return Frame(self.name, fid, timestamp_ns, image)
