"""The capture part of a studio config (``studio.toml``), read once for every command.

::

    [studio]
    name = "lab"
    session = "sessions/take1"        # replay session, relative to this file
    calibration = "calibration.toml"  # default: the session's calibration.toml

    [trigger]                         # optional USB trigger box
    backend = "none"                  # none | usb
    fps = 50.0                        # default: the replay session's fps, else DEFAULT_FPS

    [[camera]]                        # see capture.backends.SourceSpec
    name = "cam0"
    backend = "opencv"
    source = "/dev/video0"

Other tables and keys belong to the service (``service.config`` reads them on top of this);
``contourcap record`` reads only this part, so one file serves both.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from capture.backends import SourceSpec, parse_source_specs
from capture.session import SessionError, load_session
from capture.tomlio import tomllib

__all__ = ["DEFAULT_FPS", "TRIGGER_BACKENDS", "StudioCapture", "read_studio_toml", "parse_studio_capture"]

DEFAULT_FPS = 30.0
"""Frames per second without ``[trigger] fps`` and without a replay session: what UVC cameras deliver by default."""
TRIGGER_BACKENDS = ("none", "usb")


@dataclass(frozen=True)
class StudioCapture:
    """What capture reads from ``studio.toml``.

    Attributes
    ----------
    name : str
        ``[studio] name`` (default ``"studio"``).
    session : Path or None
        ``[studio] session``, resolved against the config's folder.
    calibration : Path or None
        ``[studio] calibration``, resolved; None: the session's.
    trigger : {"none", "usb"}
        ``[trigger] backend``.
    fps : float
        Frames per second of the studio (trigger rate, requested camera rate): ``[trigger] fps``, else
        the replay session's when replay cameras use one, else :data:`DEFAULT_FPS`.
    trigger_options : mapping
        The other ``[trigger]`` keys, unread here.
    cameras : tuple of SourceSpec
        The ``[[camera]]`` tables.
    """

    name: str
    session: Path | None
    calibration: Path | None
    trigger: str
    fps: float
    cameras: tuple[SourceSpec, ...]
    trigger_options: Mapping[str, Any] = field(default_factory=dict)


def read_studio_toml(path) -> dict:
    """The parsed TOML of ``path``; ``ValueError`` naming the file if unreadable or not TOML."""
    path = Path(path)
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None


def _path(value: Any, key: str, where: str, base: Path | None) -> Path | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise ValueError(f"{where}: {key}: expected a path (string), got {value!r}")
    p = Path(value).expanduser()
    return p if p.is_absolute() or base is None else base / p


def parse_studio_capture(data: Mapping[str, Any], *, where: str = "<config>",
                         base: Path | None = None) -> StudioCapture:
    """Validate the capture part of a parsed ``studio.toml``.

    Parameters
    ----------
    data : mapping
        The whole parsed file (tables capture does not use are ignored).
    where : str
        File name for the error messages.
    base : Path, optional
        Folder that relative paths are resolved against (the config's).

    Returns
    -------
    StudioCapture

    Raises
    ------
    ValueError
        Naming ``where`` and the key.  The replay session is loaded (``fps`` default) only when
        ``[trigger] fps`` is absent and replay cameras use it.
    """
    studio, trigger = data.get("studio", {}), data.get("trigger", {})
    if not isinstance(studio, dict) or not isinstance(trigger, dict):
        raise ValueError(f"{where}: [studio] and [trigger] must be tables")
    cameras = parse_source_specs(data.get("camera"), where=where)
    session = _path(studio.get("session"), "studio.session", where, base)
    replay = any(c.backend == "replay" for c in cameras)
    if replay and session is None:
        raise ValueError(f"{where}: studio.session: replay cameras need a session directory")
    backend = trigger.get("backend", "none")
    if backend not in TRIGGER_BACKENDS:
        raise ValueError(f"{where}: trigger.backend: must be one of {list(TRIGGER_BACKENDS)}, got {backend!r}")
    fps = trigger.get("fps")
    if fps is None:
        fps = DEFAULT_FPS
        if replay:
            try:
                fps = load_session(session, require_calibration=False).fps
            except SessionError as exc:  # names the session's file
                raise ValueError(str(exc)) from None
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0:
        raise ValueError(f"{where}: trigger.fps: must be a positive number, got {fps!r}")
    name = studio.get("name", "studio")
    if not isinstance(name, str) or not name:
        raise ValueError(f"{where}: studio.name: expected a non-empty string, got {name!r}")
    return StudioCapture(
        name=name, session=session, calibration=_path(studio.get("calibration"), "studio.calibration", where, base),
        trigger=backend, fps=float(fps), cameras=cameras,
        trigger_options={k: v for k, v in trigger.items() if k not in ("backend", "fps")})
