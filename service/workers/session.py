"""The studio's replay session, loaded for the workers that need it (replay cameras, segmenters, the tracker)."""

from __future__ import annotations

from capture.session import Session, load_session
from service.config import ConfigError, StudioConfig

__all__ = ["studio_session"]


def studio_session(cfg: StudioConfig) -> Session:
    """The session of ``[studio] session``, loaded.

    Raises
    ------
    ConfigError
        The config names no session.
    SessionError
        The session does not load (the message names the file).
    """
    if cfg.session is None:
        raise ConfigError(f"{cfg.path}: studio.session: needed for replay cameras / calibration")
    return load_session(cfg.session)
