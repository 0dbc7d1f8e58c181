"""Studio configuration (``studio.toml``): typed, validated, every error names the key.

::

    [studio]
    name = "lab"                      # zenoh key prefix contourcap/<name>/...
    delivery = "live"                 # live | lossless
    session = "sessions/take1"        # replay session (relative to this file) for backend = "replay"
    calibration = "calibration.toml"  # default: the session's calibration.toml
    model = "knossow40"               # body model name or file
    jpeg_quality = 90

    [zenoh]                           # see service.wire.bus.ZenohSettings
    mode = "peer"                     # peer | client | router
    listen = ["tcp/127.0.0.1:7447"]
    connect = []
    tls_root_ca = "certs/ca.pem"      # optional, paths relative to this file
    user = "contourcap"               # optional usrpwd auth; password from password_file
    password_file = "secrets/zenoh_password"

    [trigger]                         # optional USB trigger box
    backend = "none"                  # none | usb
    fps = 50.0                        # default: the replay session's fps, else 30 (capture.studio)

    [tracker]
    host = "host-a"
    set_timeout_ms = 80               # live: wait this long for missing cameras
    window = 8                        # lossless: frames in flight before the cameras wait
    method = "contours"               # contours (Knossow) | blobs (BMVC'04: the track worker reads the frames)
    auto_subject = true               # live, no subject file: calibrate the subject beside the stream
    auto_subject_frames = 9           # frame sets it samples (a third held out to judge the result)
    auto_subject_nice = 10            # nice levels the calibration thread runs below the process

    [router]                          # optional: `contourcap run` on this host also runs the router
    host = "host-a"
    listen = ["tls/0.0.0.0:7447"]
    config_file = "zenoh/router-tls.json5"   # TLS, usrpwd and ACL (deploy/zenoh/)
    tls_cert = "certs/router.pem"            # optional overrides of the file's paths
    tls_key = "certs/router.key"
    auth_dictionary = "secrets/zenoh-users.txt"

    [[camera]]
    name = "cam0"
    host = "host-a"
    backend = "replay"                # replay | opencv
    source = "0"                      # opencv device index/URL; ignored by replay (uses studio.session)
    encoding = "raw"                  # raw | jpeg | png on the wire (raw: the segment worker is on this host)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from capture.studio import DEFAULT_FPS, parse_studio_capture, read_studio_toml
from service.errors import ServiceError
from service.wire.bus import MODES, ZenohSettings
from service.wire.messages import ENCODINGS, check_name, MessageError



METHODS = ("contours", "blobs")
"""``[tracker] method`` values."""


class ConfigError(ServiceError, ValueError):
    """A studio configuration problem; the message names the file and key."""


@dataclass(frozen=True)
class CameraConfig:
    """One ``[[camera]]`` of the studio (the capture keys as ``capture.backends.SourceSpec`` reads them).

    Attributes
    ----------
    name, host : str
        Camera name; the host it is plugged into.
    backend : {"replay", "opencv"}
    source : str
        opencv: device index, device path or video file; replay: unused.
    encoding : {"raw", "jpeg", "png"}
        Frame encoding on the wire.
    width, height : int or None
        opencv: requested capture size (pixels).
    fps : float or None
        opencv: requested rate (frames per second; default ``[trigger] fps``).
    exposure : float or None
        opencv: requested exposure (driver units).
    """

    name: str
    host: str
    backend: str = "replay"
    source: str = ""
    encoding: str = "raw"
    width: int | None = None
    height: int | None = None
    fps: float | None = None
    exposure: float | None = None


@dataclass(frozen=True)
class TriggerConfig:
    """``[trigger]``: ``backend`` ("none" or "usb"), ``fps`` (frames per second, see
    ``capture.studio.StudioCapture.fps``) and the other keys as ``options``."""

    backend: str = "none"
    fps: float = DEFAULT_FPS
    options: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class StudioConfig:
    """A validated ``studio.toml`` (the keys are in the module docstring).

    Attributes
    ----------
    path : Path or None
        The file (None when parsed from a mapping without a base folder).
    studio : str
        Studio name, the zenoh key prefix.
    delivery : {"live", "lossless"}
    session, calibration : Path or None
        Replay session; calibration file (None: the session's).
    model : str
        Body model name or file.
    jpeg_quality : int, 1..100, for ``encoding = "jpeg"`` cameras
    zenoh : ZenohSettings
    trigger : TriggerConfig
    tracker_host : str
    set_timeout_ms : float
        Live: how long a frame set waits for missing cameras (milliseconds).
    window : int
        Lossless: frames in flight before the cameras wait.
    router_host : str or None
    router : ZenohSettings or None
        ``[router]``, when this studio runs its own.
    cameras : tuple of CameraConfig
    method : {"contours", "blobs"}
        ``[tracker] method``: the contour tracker on the segment workers' chamfer images, or the blob
        tracker (``tracker.blobs``) on the camera frames themselves (no segment worker runs).
    auto_subject, auto_subject_frames, auto_subject_nice : ``[tracker]`` (module docstring)
    """

    path: Path | None
    studio: str
    delivery: str
    session: Path | None
    calibration: Path | None
    model: str
    jpeg_quality: int
    zenoh: ZenohSettings
    trigger: TriggerConfig
    tracker_host: str
    set_timeout_ms: float
    window: int
    router_host: str | None
    router: ZenohSettings | None
    cameras: tuple[CameraConfig, ...]
    method: str = "contours"
    auto_subject: bool = True
    auto_subject_frames: int = 9
    auto_subject_nice: int = 10

    @property
    def hosts(self) -> tuple[str, ...]:
        """Every host named in the config (cameras, tracker, router), first mention first."""
        hs = [c.host for c in self.cameras] + [self.tracker_host] + ([self.router_host] if self.router_host else [])
        return tuple(dict.fromkeys(hs))

    def cameras_on(self, host: str) -> tuple[CameraConfig, ...]:
        """The cameras plugged into ``host``."""
        return tuple(c for c in self.cameras if c.host == host)

    def camera(self, name: str) -> CameraConfig:
        """The camera called ``name``; ``ConfigError`` if there is none."""
        for c in self.cameras:
            if c.name == name:
                return c
        raise ConfigError(f"{self.path}: no [[camera]] named {name!r} (have {[c.name for c in self.cameras]})")


class _Reader:
    def __init__(self, where: str, base: Path | None) -> None:
        self.where, self.base = where, base

    def err(self, key: str, msg: str) -> ConfigError:
        return ConfigError(f"{self.where}: {key}: {msg}")

    def get(self, table: Mapping, key: str, prefix: str, types: tuple, default: Any = ..., choices=None) -> Any:
        full = f"{prefix}.{key}" if prefix else key
        if key not in table:
            if default is ...:
                raise self.err(full, "missing")
            return default
        v = table[key]
        if isinstance(v, bool) and bool not in types or not isinstance(v, types):
            raise self.err(full, f"expected {'/'.join(t.__name__ for t in types)}, got {v!r}")
        if choices is not None and v not in choices:
            raise self.err(full, f"must be one of {list(choices)}, got {v!r}")
        return v

    def name(self, table: Mapping, key: str, prefix: str, default: Any = ...) -> str:
        v = self.get(table, key, prefix, (str,), default)
        try:
            return check_name(v, f"{prefix}.{key}")
        except MessageError as exc:
            raise self.err(f"{prefix}.{key}", str(exc)) from None

    def path(self, table: Mapping, key: str, prefix: str) -> str | None:
        v = self.get(table, key, prefix, (str,), None)
        if v is None:
            return None
        p = Path(v).expanduser()
        return str(p if p.is_absolute() or self.base is None else self.base / p)

    def strings(self, table: Mapping, key: str, prefix: str) -> tuple[str, ...]:
        v = self.get(table, key, prefix, (list,), [])
        if not all(isinstance(s, str) for s in v):
            raise self.err(f"{prefix}.{key}", "expected a list of strings")
        return tuple(v)

    def unknown(self, table: Mapping, allowed: set, prefix: str) -> None:
        extra = sorted(set(table) - allowed)
        if extra:
            raise self.err(f"{prefix}.{extra[0]}", f"unknown key (allowed: {sorted(allowed)})")


def _zenoh(r: _Reader, z: Mapping) -> ZenohSettings:
    r.unknown(z, {"mode", "listen", "connect", "multicast_scouting", "tls_root_ca", "tls_cert", "tls_key",
                  "tls_mtls", "user", "password_file", "auth_dictionary", "config_file", "connect_timeout_s"},
              "zenoh")
    password = None
    pw_file = r.path(z, "password_file", "zenoh")
    if pw_file is not None:
        try:
            password = Path(pw_file).read_text().strip()
        except OSError as exc:
            raise r.err("zenoh.password_file", f"cannot read {pw_file}: {exc.strerror}") from None
    user = r.get(z, "user", "zenoh", (str,), None)
    if (user is None) != (password is None):
        raise r.err("zenoh.user", "user and password_file must be given together")
    try:
        return ZenohSettings(
            mode=r.get(z, "mode", "zenoh", (str,), "peer", choices=("peer", "client", "router")),
            listen=r.strings(z, "listen", "zenoh"), connect=r.strings(z, "connect", "zenoh"),
            multicast_scouting=r.get(z, "multicast_scouting", "zenoh", (bool,), False),
            tls_root_ca=r.path(z, "tls_root_ca", "zenoh"), tls_cert=r.path(z, "tls_cert", "zenoh"),
            tls_key=r.path(z, "tls_key", "zenoh"), tls_mtls=r.get(z, "tls_mtls", "zenoh", (bool,), False),
            user=user, password=password, auth_dictionary=r.path(z, "auth_dictionary", "zenoh"),
            config_file=r.path(z, "config_file", "zenoh"),
            connect_timeout_s=float(r.get(z, "connect_timeout_s", "zenoh", (int, float), 5.0)))
    except ValueError as exc:
        raise r.err("zenoh", str(exc)) from None


def parse_config(data: Mapping[str, Any], *, where: str = "<config>", base: Path | None = None) -> StudioConfig:
    """Validate a parsed studio TOML.

    Parameters
    ----------
    data : mapping
        The parsed file.
    where : str
        File name for the error messages.
    base : Path, optional
        Folder relative paths are resolved against (the file's); None leaves them relative.

    Returns
    -------
    StudioConfig
        ``ConfigError`` naming the file and key if a key is missing, unknown or invalid.
    """
    r = _Reader(where, base)
    r.unknown(data, {"studio", "zenoh", "trigger", "tracker", "router", "camera"}, "")
    s = r.get(data, "studio", "", (dict,))
    r.unknown(s, {"name", "delivery", "session", "calibration", "model", "jpeg_quality"}, "studio")
    r.get(data, "camera", "", (list,))
    try:  # the capture part (cameras, session, trigger) is read as `contourcap record` reads it
        cap = parse_studio_capture(data, where=where, base=base)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    cams = []
    for i, (c, spec) in enumerate(zip(data["camera"], cap.cameras)):
        p = f"camera[{i}]"
        cams.append(CameraConfig(r.name(c, "name", p), r.name(c, "host", p), spec.backend, str(spec.source),
                                 r.get(c, "encoding", p, (str,), "raw", choices=ENCODINGS),
                                 width=spec.width, height=spec.height, fps=spec.fps, exposure=spec.exposure))
    trigger = TriggerConfig(cap.trigger, cap.fps, dict(cap.trigger_options))
    tr = r.get(data, "tracker", "", (dict,), {})
    r.unknown(tr, {"host", "set_timeout_ms", "window", "method", "auto_subject", "auto_subject_frames",
                   "auto_subject_nice"}, "tracker")
    ro = r.get(data, "router", "", (dict,), None)
    zen = _zenoh(r, r.get(data, "zenoh", "", (dict,), {}))
    router = None
    if ro is not None:
        r.unknown(ro, {"host", "listen", "config_file", "tls_cert", "tls_key", "auth_dictionary"}, "router")
        router = ZenohSettings(mode="router", listen=r.strings(ro, "listen", "router"),
                               tls_root_ca=zen.tls_root_ca,
                               tls_cert=r.path(ro, "tls_cert", "router"), tls_key=r.path(ro, "tls_key", "router"),
                               auth_dictionary=r.path(ro, "auth_dictionary", "router"),
                               config_file=r.path(ro, "config_file", "router"))
    window = r.get(tr, "window", "tracker", (int,), 8)
    timeout = float(r.get(tr, "set_timeout_ms", "tracker", (int, float), 80.0))
    quality = r.get(s, "jpeg_quality", "studio", (int,), 90)
    auto_frames = r.get(tr, "auto_subject_frames", "tracker", (int,), 9)
    auto_nice = r.get(tr, "auto_subject_nice", "tracker", (int,), 10)
    if not 3 <= auto_frames <= 64 or not 0 <= auto_nice <= 19:
        raise r.err("tracker", "auto_subject_frames in 3..64, auto_subject_nice in 0..19")
    if window < 1 or timeout <= 0 or not 1 <= quality <= 100:
        raise r.err("tracker" if quality in range(1, 101) else "studio.jpeg_quality",
                    "window >= 1, set_timeout_ms > 0, jpeg_quality in 1..100")
    return StudioConfig(
        path=Path(where) if base is not None else None, studio=r.name(s, "name", "studio"),
        delivery=r.get(s, "delivery", "studio", (str,), "live", choices=MODES),
        session=cap.session, calibration=cap.calibration, model=r.get(s, "model", "studio", (str,), "knossow40"),
        jpeg_quality=quality, zenoh=zen, trigger=trigger,
        tracker_host=r.name(tr, "host", "tracker", cams[0].host), set_timeout_ms=timeout, window=window,
        router_host=r.name(ro, "host", "router") if ro is not None else None,
        router=router,
        cameras=tuple(cams),
        method=r.get(tr, "method", "tracker", (str,), "contours", choices=METHODS),
        auto_subject=r.get(tr, "auto_subject", "tracker", (bool,), True), auto_subject_frames=auto_frames,
        auto_subject_nice=auto_nice)


def load_config(path) -> StudioConfig:
    """Read and validate ``studio.toml``; ConfigError names the file and key."""
    path = Path(path)
    try:
        data = read_studio_toml(path)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    return parse_config(data, where=str(path), base=path.resolve().parent)
