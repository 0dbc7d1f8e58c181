"""What ``contourcap run`` checks before it starts a host's workers."""

from __future__ import annotations

from capture.calibration import load_calibration
from service.config import ConfigError, StudioConfig
from service.workers.session import studio_session

__all__ = ["preflight"]


def preflight(cfg: StudioConfig, host: str, *, fit_plugin: str | None = None) -> None:
    """Check that ``host``'s workers can start: without this each would fail and be restarted forever.

    The session (calibration, subject) that the host's tracker or replay cameras need loads, and
    every camera of the studio is calibrated.

    Parameters
    ----------
    cfg : StudioConfig
    host : str
        Host name in the config.
    fit_plugin : str, optional
        ``module:callable`` replacing the tracker (then no calibration is needed).

    Raises
    ------
    ConfigError, SessionError, CalibrationError
        Naming the file at fault.
    """
    replay = any(c.backend == "replay" for c in cfg.cameras_on(host))
    tracks = cfg.tracker_host == host and not fit_plugin
    session = studio_session(cfg) if replay or tracks else None
    if tracks:
        calibrated = ({c.name for c in load_calibration(cfg.calibration)} if cfg.calibration is not None
                      else {c.name for c in session.calibration})
        missing = [c.name for c in cfg.cameras if c.name not in calibrated]
        if missing:  # the tracker would report every frame as "unknown camera(s)"
            where = cfg.calibration or session.root / "calibration.toml"
            raise ConfigError(f"{where}: no calibration for camera(s) {missing} of {cfg.path} "
                              f"(calibrated: {sorted(calibrated)})")
