"""What a session's media hold, checked before tracking: readable, the calibrated size, long enough.

:func:`check_media` opens every selected camera's footage (and background) and decodes its first frame,
so a file that is not a video, an image size that is not the calibration's, or a ``--frames`` range
beyond the recording is one error naming the camera and the file *before* any work is done.
:class:`StreamCheck` then follows a tracking run's frame sets and names a camera whose stream ends
early or skips frames it declared (a cut or corrupt file): per camera, frames read against frames
expected.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from capture.calibration import CalibrationError
from capture.errors import CaptureError
from capture.replay import FrameRangeError, count_frames, read_frames
from capture.session import Session, image_frame_ids, read_timestamps
from capture.sources import SourceError

__all__ = ["CameraMedia", "MissingFramesError", "StreamCheck", "check_media"]


class MissingFramesError(CaptureError):
    """A camera's stream ended early or lost frames it declared (cut or corrupt media)."""


@dataclass(frozen=True)
class CameraMedia:
    """One camera's media as opened: ``frames`` expected in the selected range (None when the
    container does not say), ``size`` (width, height) in pixels of its first frame, ``declared``
    frame ids when the session lists them (timestamps CSV or image files), else None."""

    camera: str
    where: str
    frames: int | None
    size: tuple[int, int]
    declared: frozenset[int] | None = None


def _declared_ids(session: Session, name: str, frames: range | None) -> frozenset[int] | None:
    cam = session.camera(name)
    ids = None
    if cam.timestamps is not None:
        ids, _ = read_timestamps(cam.timestamps)
    elif cam.images is not None:
        ids = image_frame_ids(cam.images)
    if ids is None:
        return None
    ids = np.asarray(ids, dtype=np.int64)
    if frames is not None:
        ids = ids[(ids >= frames.start) & (ids < frames.stop)]
    return frozenset(int(i) for i in ids)


def _first_frame(session: Session, name: str, *, background: bool) -> tuple[str, tuple[int, int]] | None:
    """``(where, (width, height))`` of the first frame, None when there is none (SourceError if unreadable)."""
    cam = session.camera(name)
    where = str(cam.background if background else (cam.video if cam.video is not None else cam.images))
    it = read_frames(session, name, background=background)
    try:
        frame = next(it, None)
    finally:
        it.close()
    if frame is None:
        return None
    h, w = frame.image.shape[:2]
    return where, (int(w), int(h))


def check_media(session: Session, cameras: Sequence[str], *, frames: range | None = None) -> dict[str, CameraMedia]:
    """Open each camera's footage (and background) and check it against the session.

    Parameters
    ----------
    session : Session
    cameras : sequence of str
        The cameras to check.
    frames : range or None
        The frame ids that will be read (None: all).

    Returns
    -------
    dict of str to CameraMedia

    Raises
    ------
    SourceError
        A file that cannot be opened or decoded (named, with its camera).
    CalibrationError
        An image size that differs from the calibration's for that camera.
    FrameRangeError
        ``frames`` holds none of the recorded frame ids (the recording's length named).
    """
    calib = {c.name: c for c in session.calibration}
    out: dict[str, CameraMedia] = {}
    for name in cameras:
        try:
            first = _first_frame(session, name, background=False)
        except SourceError as exc:
            raise type(exc)(f"camera {name!r}: {exc}") from None
        if first is None:
            raise SourceError(f"camera {name!r}: {session.camera(name).video or session.camera(name).images}: "
                              "holds no decodable frame")
        where, size = first
        sizes = [(where, size)]
        if session.camera(name).background is not None:
            try:
                bg = _first_frame(session, name, background=True)
            except SourceError as exc:
                raise type(exc)(f"camera {name!r} background: {exc}") from None
            if bg is None:
                raise SourceError(f"camera {name!r}: background {session.camera(name).background}: "
                                  "holds no decodable frame")
            sizes.append(bg)
        if name in calib:
            want = tuple(int(v) for v in calib[name].size)
            for w, got in sizes:
                if got != want:
                    raise CalibrationError(
                        f"camera {name!r}: {w} is {got[0]}x{got[1]} but the calibration "
                        f"({session.root / 'calibration.toml'}) is for {want[0]}x{want[1]} images: "
                        "a calibration of another camera or resolution")
        out[name] = CameraMedia(name, where, count_frames(session, name, None), size,
                                _declared_ids(session, name, None))
    if frames is not None:
        _check_range(out, frames)
        out = {n: CameraMedia(m.camera, m.where, count_frames(session, n, frames), m.size,
                              _declared_ids(session, n, frames)) for n, m in out.items()}
    return out


def _check_range(media: dict[str, CameraMedia], frames: range) -> None:
    """FrameRangeError when ``frames`` starts after every camera's last frame."""
    lasts = []
    for m in media.values():
        if m.declared:
            lasts.append(max(m.declared))
        elif m.frames:
            lasts.append(m.frames - 1)
    if lasts and frames.start > max(lasts):
        stop = "end" if frames.stop >= 2**62 else frames.stop
        raise FrameRangeError(f"--frames {frames.start}:{stop}: the session holds frames 0..{max(lasts)} "
                              f"({max(lasts) + 1} frames)")


@dataclass
class StreamCheck:
    """Follows a run's frame sets and finds cameras whose streams fail.

    A camera absent from a set is *missing* unless it declared it does not hold that id (timestamps
    CSV or image files: a dropped frame).  ``allow_missing``: missing frames are counted (the run goes
    on with the cameras present), else the first is a :class:`MissingFramesError` naming the camera,
    its frames read and expected.
    """

    media: dict[str, CameraMedia]
    allow_missing: bool = False
    read: dict[str, int] = field(default_factory=dict)
    missing: dict[str, int] = field(default_factory=dict)

    def see(self, frame_id: int, present: Sequence[str]) -> list[str]:
        """Record one set; returns the cameras missing from it (MissingFramesError unless allowed)."""
        present = set(present)
        gone = []
        for name, m in self.media.items():
            if name in present:
                self.read[name] = self.read.get(name, 0) + 1
            elif m.declared is None or frame_id in m.declared:
                gone.append(name)
                self.missing[name] = self.missing.get(name, 0) + 1
        if gone and not self.allow_missing:
            name = gone[0]
            raise MissingFramesError(f"camera {name!r}: no frame {frame_id} in {self.media[name].where} "
                                     f"({self.describe(name)}): the file is cut short or corrupt; "
                                     "--allow-missing-cameras tracks on with the other cameras")
        return gone

    def check_lengths(self) -> list[str]:
        """Before the run: cameras without declared frame ids whose containers hold fewer frames than
        the longest camera's.  MissingFramesError naming the first unless ``allow_missing``; returns
        one line per short camera."""
        longest = max((m.frames for m in self.media.values() if m.frames is not None), default=None)
        short = [m for m in self.media.values()
                 if m.declared is None and m.frames is not None and longest is not None and m.frames < longest]
        lines = [f"camera {m.camera}: {m.where} holds {m.frames} frames, the longest camera {longest}"
                 for m in short]
        if short and not self.allow_missing:
            raise MissingFramesError(f"{lines[0]}: the file is cut short or corrupt; --allow-missing-cameras "
                                     "tracks on with the other cameras")
        return lines

    def describe(self, name: str) -> str:
        """``"40 frames read of 60 expected"`` for one camera."""
        m = self.media[name]
        longest = max((x.frames for x in self.media.values() if x.frames is not None), default=None)
        expected = len(m.declared) if m.declared is not None else longest
        return f"{self.read.get(name, 0)} frames read of {expected if expected is not None else '?'} expected"

    def report(self) -> list[str]:
        """One line per camera that missed frames."""
        return [f"camera {n}: {self.missing[n]} frame(s) missing, {self.describe(n)}" for n in sorted(self.missing)]
