"""The live tracker's automatic subject calibration: sampled while tracking, fitted beside it.

When the studio names no subject file, :class:`AutoSubject` offers every usable fit (the search
idle; ``tracker.fitting.subject_auto.usable_record``) with its silhouettes to a bounded, diverse
``tracker.fitting.subject_auto.SubjectSample``;
once ``options.offers`` sets were offered it fits and judges the subject (``calibrate_sample``) in
a daemon thread whose niceness is raised by ``nice`` (the fitting thread keeps its priority: poses
go on going out, one per set).  Once, it calibrates; when the calibrated body explains the
held-out sets better it is handed to the fitter at a frame boundary (:meth:`AutoSubject.take_body`),
written as a subject file at ``out_path`` when given (atomically) and kept as a
:class:`~service.wire.subject.SubjectMessage` for the track worker to publish on
``contourcap/<studio>/subject`` (:meth:`AutoSubject.message`).  A body not better is dropped
(logged); nothing else changes.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from service.atomic import write_text_atomic
from service.wire.subject import SubjectMessage
from service.workers.base import renice_thread
from tracker.fitting.subject_auto import (AutoSubjectOptions, SampleCalibration, SubjectSample, calibrate_sample,
                                         usable_record)

__all__ = ["AutoSubject", "AutoSubjectState", "AUTO_SUBJECT_FILE", "DEFAULT_NICE", "studio_auto_subject"]

log = logging.getLogger("contourcap.worker")

DEFAULT_NICE = 10
"""Nice levels the calibration thread is lowered by (the fitting thread is raised, ``track.py``)."""
AUTO_SUBJECT_FILE = "subject_auto.toml"
"""The adopted subject's file name in the session directory (when the worker may write there)."""


@dataclass(frozen=True)
class AutoSubjectState:
    """Where an automatic calibration is: ``"sampling"``, ``"fitting"``, ``"adopted"``,
    ``"rejected"`` or ``"failed"``, with the result once there is one."""

    state: str
    result: SampleCalibration | None = None
    wall_s: float | None = None


class AutoSubject:
    """Sample, calibrate beside the stream, hand over a better body (module docstring).

    Parameters
    ----------
    model : BodyModel
        The tracker's body at the start.
    cameras : sequence of Camera
        The studio's cameras (a set's silhouettes are taken only when it has all of them).
    options : AutoSubjectOptions
    out_path : Path, optional
        Where the adopted subject is written (None: nowhere).
    name : str
        The pose record's ``subject`` once adopted (default: ``out_path``'s name, else ``"auto"``).
    nice : int
        Nice levels the calibration thread is lowered by (0: as the caller).
    background : bool
        Run the calibration in a thread (False: in :meth:`observe`'s caller, for tests of the logic).
    """

    def __init__(self, model, cameras, options: AutoSubjectOptions = AutoSubjectOptions(), *,
                 out_path: Path | None = None, name: str | None = None, nice: int = DEFAULT_NICE,
                 background: bool = True) -> None:
        self.model, self.cameras, self.options = model, list(cameras), options
        self.out_path = None if out_path is None else Path(out_path)
        self.name = name or (self.out_path.name if self.out_path is not None else "auto")
        self.nice, self.background = int(nice), bool(background)
        self.sample = SubjectSample(model, options.frames, options.min_gap)
        self._lock = threading.Lock()
        self._state = AutoSubjectState("sampling")
        self._body = None  # the adopted body until taken
        self._message: SubjectMessage | None = None
        self._thread: threading.Thread | None = None

    @property
    def state(self) -> AutoSubjectState:
        """The calibration's state (see :class:`AutoSubjectState`)."""
        with self._lock:
            return self._state

    def observe(self, frame_id: int, record: dict, silhouettes: dict) -> None:
        """Offer a fitted set (its pose record and camera -> silhouette) to the sample when usable; start the
        calibration once ``options.offers`` were offered."""
        if self._state.state != "sampling" or not usable_record(record, self.options.min_iou):
            return
        if any(c.name not in silhouettes for c in self.cameras):
            return
        self.sample.offer(frame_id, np.asarray(record["params"], float), {c.name: silhouettes[c.name]
                                                                          for c in self.cameras})
        if self.sample.offered >= self.options.offers and len(self.sample) >= self.options.frames:
            self._start()

    def _start(self) -> None:
        sets, model = self.sample.sets(), self.model
        with self._lock:
            self._state = AutoSubjectState("fitting")
        if not self.background:
            self._calibrate(sets, model)
            return
        self._thread = threading.Thread(target=self._calibrate, args=(sets, model), name="auto-subject", daemon=True)
        self._thread.start()

    def _lower_priority(self) -> None:
        exc = renice_thread(self.nice) if self.nice > 0 and self.background else None
        if exc is not None:
            log.info("subject calibration's priority not lowered (%s)", exc)

    def _calibrate(self, sets, model) -> None:
        self._lower_priority()
        w0 = time.perf_counter()
        try:
            res = calibrate_sample(model, self.cameras, sets, self.options,
                                   where=f"contourcap live tracker, frames {sets[0][0]}..{sets[-1][0]}")
        except Exception as exc:  # a failed calibration leaves the tracker's body as it is
            log.warning("subject calibration failed: %s", exc)
            with self._lock:
                self._state = AutoSubjectState("failed", wall_s=time.perf_counter() - w0)
            return
        wall = time.perf_counter() - w0
        log.info("subject calibration: held-out IoU %.4f -> %.4f (%s), %.1f s CPU, %.1f s wall", res.iou_current,
                 res.iou_calibrated, "adopted" if res.adopted else "not better: kept the body", res.cpu_s, wall)
        message = SubjectMessage.of(res.subject) if res.adopted else None
        if message is not None and self.out_path is not None:
            try:
                write_text_atomic(self.out_path, message.text)
            except OSError as exc:
                log.warning("subject not written to %s: %s", self.out_path, exc)
        with self._lock:
            self._state = AutoSubjectState("adopted" if res.adopted else "rejected", res, wall)
            if res.adopted:
                self._body, self._message = res.fit.model, message

    def take_body(self):
        """The adopted body, once (None before, after and when none was adopted)."""
        with self._lock:
            body, self._body = self._body, None
        return body

    def message(self) -> SubjectMessage | None:
        """The adopted subject's message (None until one is adopted)."""
        with self._lock:
            return self._message

    @property
    def running(self) -> bool:
        """A calibration thread is running."""
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout_s: float | None = None) -> None:
        """Wait for a running calibration thread (tests, shutdown)."""
        if self._thread is not None:
            self._thread.join(timeout_s)


def studio_auto_subject(tracker, root, frames: int, *, nice: int = DEFAULT_NICE) -> AutoSubject:
    """The live track worker's :class:`AutoSubject` for ``tracker`` (its model and cameras): ``frames``
    sets sampled from three times as many good ones, a third held out; the adopted subject written
    to ``root / AUTO_SUBJECT_FILE`` when ``root`` is a writable directory."""
    root = Path(root)
    writable = root.is_dir() and os.access(root, os.W_OK)
    return AutoSubject(tracker.model, list(tracker.cameras.values()), AutoSubjectOptions.for_sample(frames),
                       out_path=root / AUTO_SUBJECT_FILE if writable else None, nice=nice)
