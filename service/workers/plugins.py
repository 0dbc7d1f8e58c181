"""A worker's processing parts: plug-ins (``module:callable``) or the real segmenter and tracker."""

from __future__ import annotations

import importlib
from dataclasses import replace
from typing import Callable

from service.config import ConfigError, StudioConfig
from service.workers.session import studio_session

__all__ = ["load_plugin", "build_segmenters", "build_fitter"]


def load_plugin(spec: str) -> Callable:
    """``module:callable`` -> the callable (a local, user-given plug-in; never from the network).

    Raises
    ------
    ConfigError
        Malformed spec, import failure or not callable.
    """
    mod, _, attr = spec.partition(":")
    if not mod or not attr:
        raise ConfigError(f"plug-in {spec!r}: expected 'module:callable'")
    try:
        obj = getattr(importlib.import_module(mod), attr)
    except (ImportError, AttributeError) as exc:
        raise ConfigError(f"plug-in {spec!r}: {exc}") from None
    if not callable(obj):
        raise ConfigError(f"plug-in {spec!r}: not callable")
    return obj


def build_segmenters(cfg: StudioConfig, cameras: tuple[str, ...], *, plugin: str | None = None) -> dict:
    """One segmenter per camera (name -> ``Segmenter``).

    A plug-in factory ``f(camera) -> Segmenter``, else
    :class:`~service.workers.components.BackgroundSegmenter` with the session's background model as
    ``service.backgrounds`` builds it (replay cameras: so lossless replay gives the offline poses) or
    learnt from the first frames (live cameras: the studio must be empty at start-up).
    """
    if plugin:
        factory = load_plugin(plugin)
        return {c: factory(c) for c in cameras}
    from service.workers.components import BackgroundSegmenter

    replayed = [c for c in cameras if cfg.camera(c).backend == "replay"]
    models = {}
    if replayed:
        from service.backgrounds import background_models

        models, _ = background_models(studio_session(cfg), replayed)
    return {c: BackgroundSegmenter(model=models.get(c)) for c in cameras}


def build_fitter(cfg: StudioConfig, *, plugin: str | None = None) -> Callable:
    """The track worker's ``Fitter``: a plug-in factory ``f(cfg) -> Fitter``, else the tracker
    (:class:`~service.workers.components.TrackerFitter`; live delivery:
    :class:`~service.workers.live_fit.LiveTrackerFitter`) on the session's subject and calibration
    (``[studio] calibration`` replaces the session's); a live one without a subject file calibrates
    the subject beside the stream unless ``[tracker] auto_subject = false``."""
    if plugin:
        return load_plugin(plugin)(cfg)
    if cfg.method == "blobs":  # [tracker] method = "blobs": the blob tracker reads the frames itself
        return _blob_fitter(cfg)
    from service.workers.components import TrackerFitter

    session = studio_session(cfg)
    if cfg.calibration is not None:
        from capture.calibration import load_calibration

        session = replace(session, calibration=tuple(load_calibration(cfg.calibration)))
    if cfg.delivery == "live":
        from service.workers.live_fit import LiveTrackerFitter

        fitter = LiveTrackerFitter.from_session(session, model=cfg.model)
        if cfg.auto_subject and session.subject_file is None:
            from service.workers.auto_subject import studio_auto_subject

            fitter.auto_subject = studio_auto_subject(fitter.tracker, session.root, cfg.auto_subject_frames,
                                                      nice=cfg.auto_subject_nice)
        return fitter
    return TrackerFitter.from_session(session, model=cfg.model)


def _blob_fitter(cfg: StudioConfig) -> Callable:
    """``service.workers.blob_track.BlobFitter`` on the session's subject and calibration; replay
    cameras take the session's background models, live ones learn theirs from their first frames."""
    from service.workers.blob_track import BlobFitter

    session = studio_session(cfg)
    if cfg.calibration is not None:
        from capture.calibration import load_calibration

        session = replace(session, calibration=tuple(load_calibration(cfg.calibration)))
    replayed = [c.name for c in cfg.cameras if c.backend == "replay"]
    return BlobFitter.from_session(session, model=cfg.model, replayed=replayed)
