"""Zenoh wiring: key names, session configuration, publishers, bounded inboxes, liveliness and stats.

Keys (``<studio>`` configurable, default ``"default"``)::

    contourcap/<studio>/cam/<cam>/frame        FrameMessage bytes
    contourcap/<studio>/cam/<cam>/chamfer      ChamferMessage bytes
    contourcap/<studio>/pose                   pose record JSON
    contourcap/<studio>/status/<component>     StatusMessage JSON + a liveliness token
    contourcap/<studio>/credit/<consumer>      CreditMessage JSON (lossless back-pressure)
    contourcap/<studio>/cam/<cam>/have         HaveMessage JSON (live: frame ids a segment worker holds)
    contourcap/<studio>/demand/<consumer>      DemandMessage JSON (live: the frame id to segment next)

The default configuration is a peer on loopback with multicast scouting off: no router needed.

Delivery modes (see :class:`Inbox`): ``live`` keeps the newest ``depth`` messages and counts the
ones it overwrites; ``lossless`` publishes reliably with congestion control *block* and queues in
order; producers additionally wait for the consumer's credit (:class:`CreditGate`) so queues stay
bounded.  Every received payload is decoded and validated in the subscriber callback; a bad one is
counted (``Inbox.bad``), logged (rate limited) and dropped — never fatal.
"""

from __future__ import annotations

import collections
import json
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable, Generic, NamedTuple, TypeVar

import zenoh

from service.errors import ServiceError
from service.text import printable
from service.wire.messages import MessageError, check_name
from service.wire.records import CreditMessage, StatusMessage

log = logging.getLogger("contourcap.bus")
T = TypeVar("T")
MODES = ("live", "lossless")


class BusError(ServiceError, RuntimeError):
    """The zenoh session could not be opened or reached no peer/router (wrong address, TLS, credentials)."""


class Keys:
    """Key expressions of one studio, all under ``contourcap/<studio>/``.

    A name argument left at ``"*"`` gives the wildcard expression (subscriptions to every camera,
    component or consumer).
    """

    def __init__(self, studio: str = "default") -> None:
        self.studio = check_name(studio, "studio")
        self.root = f"contourcap/{self.studio}"

    def frame(self, cam: str = "*") -> str:
        """``cam/<cam>/frame``: a camera's FrameMessages."""
        return f"{self.root}/cam/{cam}/frame"

    def chamfer(self, cam: str = "*") -> str:
        """``cam/<cam>/chamfer``: a camera's ChamferMessages."""
        return f"{self.root}/cam/{cam}/chamfer"

    @property
    def pose(self) -> str:
        """``pose``: the tracker's PoseRecords."""
        return f"{self.root}/pose"

    @property
    def hull(self) -> str:
        """``hull``: the blob tracker's coloured hull per frame (``service.wire.hull.HullMessage``)."""
        return f"{self.root}/hull"

    @property
    def subject(self) -> str:
        """``subject``: a fitted subject, subject-file TOML text (``service.wire.subject.SubjectMessage``)."""
        return f"{self.root}/subject"

    def status(self, component: str = "*") -> str:
        """``status/<component>``: StatusMessages and liveliness tokens."""
        return f"{self.root}/status/{component}"

    def credit(self, consumer: str = "*") -> str:
        """``credit/<consumer>``: lossless acknowledgements (CreditMessage)."""
        return f"{self.root}/credit/{consumer}"

    def have(self, cam: str = "*") -> str:
        """``cam/<cam>/have``: the frame ids a segment worker holds (HaveMessage)."""
        return f"{self.root}/cam/{cam}/have"

    def demand(self, consumer: str = "*") -> str:
        """``demand/<consumer>``: the frame a consumer wants segmented (DemandMessage)."""
        return f"{self.root}/demand/{consumer}"

    def camera_of(self, key: str) -> str | None:
        """``cam`` from ``.../cam/<cam>/...`` or None."""
        parts = str(key).split("/")
        return parts[3] if len(parts) >= 5 and parts[2] == "cam" else None


@dataclass(frozen=True)
class ZenohSettings:
    """How to reach the other processes.  Paths are files on this host.

    Attributes
    ----------
    mode : {"peer", "client", "router"}
    listen, connect : tuple of str
        Zenoh endpoints such as ``tcp/127.0.0.1:7447`` or ``tls/host:7447``.
    multicast_scouting : bool
    tls_root_ca, tls_cert, tls_key : str or None
        PEM files; ``tls_mtls`` asks for client certificates.
    user, password : str or None
        usrpwd authentication (both or neither).
    auth_dictionary : str or None
        Routers: a file of ``user:password`` lines.
    config_file : str or None
        A zenoh JSON5 file applied first (the fields above override it).
    connect_timeout_s : float
        How long to wait for a peer/router when ``connect`` is set before :class:`BusError` (seconds).
    """

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    tls_root_ca: str | None = None
    tls_cert: str | None = None
    tls_key: str | None = None
    tls_mtls: bool = False
    user: str | None = None
    password: str | None = None
    auth_dictionary: str | None = None
    config_file: str | None = None
    connect_timeout_s: float = 5.0

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, got {self.mode!r}")
        if (self.user is None) != (self.password is None):
            raise ValueError("zenoh user and password must be given together")

    @staticmethod
    def loopback(port: int, *, listen: bool) -> "ZenohSettings":
        """The embedded default: a peer on ``tcp/127.0.0.1:<port>`` (listening or connecting)."""
        ep = (f"tcp/127.0.0.1:{int(port)}",)
        # connecting peers also listen on an ephemeral loopback port so that gossip scouting can
        # mesh them with each other (peers do not forward for one another)
        return ZenohSettings(listen=ep) if listen else ZenohSettings(connect=ep, listen=("tcp/127.0.0.1:0",))


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (for tests and the loopback demo)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def zenoh_config(s: ZenohSettings) -> zenoh.Config:
    """Build a ``zenoh.Config`` from settings (multicast scouting off unless asked for)."""
    cfg = zenoh.Config.from_file(s.config_file) if s.config_file else zenoh.Config()

    def put(key: str, value) -> None:
        cfg.insert_json5(key, json.dumps(value))

    put("mode", s.mode)
    put("scouting/multicast/enabled", bool(s.multicast_scouting))
    if s.listen or not s.config_file:
        put("listen/endpoints", list(s.listen))
    if s.connect or not s.config_file:
        put("connect/endpoints", list(s.connect))
    if s.tls_root_ca:
        put("transport/link/tls/root_ca_certificate", s.tls_root_ca)
    if s.tls_cert and s.tls_key:
        put("transport/link/tls/listen_certificate", s.tls_cert)
        put("transport/link/tls/listen_private_key", s.tls_key)
        if s.tls_mtls:
            put("transport/link/tls/connect_certificate", s.tls_cert)
            put("transport/link/tls/connect_private_key", s.tls_key)
    if s.tls_mtls:
        put("transport/link/tls/enable_mtls", True)
    if s.user is not None:
        put("transport/auth/usrpwd/user", s.user)
        put("transport/auth/usrpwd/password", s.password)
    if s.auth_dictionary:
        put("transport/auth/usrpwd/dictionary_file", s.auth_dictionary)
    return cfg


def _open_retrying(s: ZenohSettings, clock: Callable[[], float]) -> zenoh.Session:
    """``zenoh.open``; a client (which fails at once when no router answers) retries until the timeout."""
    deadline = clock() + s.connect_timeout_s
    while True:
        try:
            return zenoh.open(zenoh_config(s))
        except Exception as exc:  # zenoh.ZError and config errors
            if s.mode == "client" and s.connect and clock() < deadline:
                time.sleep(0.1)
                continue
            hint = (f"no zenoh router reachable at {list(s.connect)} within {s.connect_timeout_s:g} s: check the "
                    "address, that the router runs, TLS certificates and user/password"
                    if s.connect and "connect" in str(exc).lower()
                    else f"cannot open zenoh session (mode={s.mode}, listen={list(s.listen)})")
            raise BusError(f"{hint} (zenoh: {str(exc).split(' at /')[0]})") from exc


def open_session(s: ZenohSettings, *, clock: Callable[[], float] = time.monotonic) -> zenoh.Session:
    """Open a session; when ``connect`` endpoints are set, wait until a peer or router is reachable.

    Zenoh itself fails silently on a wrong address, certificate or password (it keeps retrying);
    this raises :class:`BusError` naming the endpoints instead.
    """
    session = _open_retrying(s, clock)
    if s.connect:
        deadline = clock() + s.connect_timeout_s
        while not (any(True for _ in session.info.peers_zid()) or any(True for _ in session.info.routers_zid())):
            if clock() > deadline:
                session.close()
                raise BusError(
                    f"no zenoh peer or router reachable at {list(s.connect)} after {s.connect_timeout_s:g} s: "
                    "check the address, that the router runs, TLS certificates and user/password")
            time.sleep(0.02)
    return session


class Received(NamedTuple):
    """One decoded message: its key, the message, and the sender's wall-clock ``sent_ns`` (or None)."""

    key: str
    message: object
    sent_ns: int | None


def attachment_ns(wall_ns: int) -> bytes:
    """The 8-byte attachment carrying a capture wall-clock time (latency measurement)."""
    return int(wall_ns).to_bytes(8, "little", signed=False)


def sent_ns_of(sample: zenoh.Sample) -> int | None:
    """The wall-clock time of a sample's :func:`attachment_ns` attachment, or None."""
    att = sample.attachment
    if att is None:
        return None
    raw = att.to_bytes()
    return int.from_bytes(raw, "little") if len(raw) == 8 else None


class Inbox(Generic[T]):
    """A bounded queue filled by a zenoh subscriber callback with decoded, validated messages.

    ``mode="live"``: holds at most ``depth`` items, the oldest is overwritten (counted in
    ``dropped``).  ``mode="lossless"``: FIFO up to ``depth`` (producers keep under it via credits;
    overflow is still counted, never blocking zenoh's thread).  ``recv(timeout_s)`` returns
    :class:`Received` ``(key, message, sent_ns)`` or None.  Inboxes given the same ``cv`` (a
    ``threading.Condition``) can be waited on together with :func:`wait_any`.  ``latest_per_key``: only
    the newest item of each key is kept (for state notices such as ``have``: a flood on one key then
    never pushes another key's notice out; a superseded item is not counted as dropped).  ``keep``:
    called with a decoded message's key and message; False drops it before it takes a place or wakes
    a reader (counted in ``refused``).
    """

    def __init__(self, session: zenoh.Session, key: str, decode: Callable[[bytes], T], *,
                 mode: str = "live", depth: int = 4, cv: threading.Condition | None = None,
                 latest_per_key: bool = False, keep: Callable[[str, T], bool] | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"delivery mode must be one of {MODES}, got {mode!r}")
        self.key, self.mode, self.depth = key, mode, int(depth)
        self._decode, self._keep = decode, keep
        self.latest_per_key = bool(latest_per_key)
        self._items: collections.deque | collections.OrderedDict = (
            collections.OrderedDict() if self.latest_per_key else collections.deque())
        self._cv = cv if cv is not None else threading.Condition()
        self.received = self.dropped = self.bad = self.refused = 0
        self._last_log = 0.0
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        sent_ns = sent_ns_of(sample)
        try:
            msg = self._decode(sample.payload.to_bytes())
        except MessageError as exc:
            with self._cv:
                self.bad += 1
            now = time.monotonic()
            if now - self._last_log > 1.0:
                self._last_log = now
                log.warning("bad message on %s (%d so far): %s", printable(key), self.bad, printable(exc))
            return
        if self._keep is not None and not self._keep(key, msg):
            with self._cv:
                self.refused += 1
            return
        with self._cv:
            self.received += 1
            if self.latest_per_key:
                self._items.pop(key, None)
            if len(self._items) >= self.depth:
                self._pop()
                self.dropped += 1
            if self.latest_per_key:
                self._items[key] = Received(key, msg, sent_ns)
            else:
                self._items.append(Received(key, msg, sent_ns))
            self._cv.notify_all()

    def _pop(self) -> Received:
        return self._items.popitem(last=False)[1] if self.latest_per_key else self._items.popleft()

    def recv(self, timeout_s: float | None = None) -> Received | None:
        """The oldest item, waiting up to ``timeout_s`` seconds (None: forever); None on timeout."""
        with self._cv:
            if not self._items and not self._cv.wait_for(lambda: bool(self._items), timeout_s):
                return None
            return self._pop()

    def drain(self) -> list[Received]:
        """Every item held, oldest first, without waiting."""
        with self._cv:
            out = list(self._items.values() if self.latest_per_key else self._items)
            self._items.clear()
            return out

    def __len__(self) -> int:
        return len(self._items)

    def close(self) -> None:
        """Undeclare the subscriber (items held stay readable)."""
        try:
            self._sub.undeclare()
        except Exception:  # session already closed
            pass


def wait_any(inboxes: "list[Inbox]", timeout_s: float) -> bool:
    """Wait until any of ``inboxes`` (sharing one ``cv``) holds an item; False on timeout."""
    cv = inboxes[0]._cv
    if any(i._cv is not cv for i in inboxes):
        raise ValueError("wait_any: the inboxes must share one condition (Inbox(..., cv=...))")
    with cv:
        return cv.wait_for(lambda: any(i._items for i in inboxes), timeout_s)


def declare_publisher(session: zenoh.Session, key: str, *, mode: str = "live") -> zenoh.Publisher:
    """Live: congestion control drop + express (latest wins).  Lossless: reliable + block."""
    if mode not in MODES:
        raise ValueError(f"delivery mode must be one of {MODES}, got {mode!r}")
    if mode == "lossless":
        return session.declare_publisher(key, reliability=zenoh.Reliability.RELIABLE,
                                         congestion_control=zenoh.CongestionControl.BLOCK)
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.DROP, express=True)


class CreditGate:
    """Producer side of lossless back-pressure: frame ``k`` may be published once every consumer
    in ``consumers`` has acknowledged frame ``k - window`` (or earlier frames were never sent)."""

    def __init__(self, session: zenoh.Session, keys: Keys, consumers: tuple[str, ...], *, window: int = 8,
                 first_frame: int | None = None) -> None:
        self.window, self.first_frame = int(window), first_frame  # None: the first frame waited for
        self._acked = {c: -1 for c in consumers}
        self._inbox = Inbox(session, keys.credit("*"), CreditMessage.from_bytes, mode="live", depth=64)

    def _take(self, credit: CreditMessage) -> None:
        if credit.consumer in self._acked:
            self._acked[credit.consumer] = max(self._acked[credit.consumer], credit.frame_id)

    def acked(self) -> int:
        """The lowest frame id every consumer has finished (-1 if none)."""
        for item in self._inbox.drain():
            self._take(item.message)
        return min(self._acked.values()) if self._acked else 2**62

    def wait(self, frame_id: int, *, timeout_s: float, stop: threading.Event | None = None) -> bool:
        """Block until ``frame_id`` may be sent; False on timeout or ``stop``."""
        deadline = time.monotonic() + timeout_s
        if self.first_frame is None:
            self.first_frame = frame_id
        while frame_id - self.window > self.acked() and frame_id - self.window >= self.first_frame:
            if (stop is not None and stop.is_set()) or time.monotonic() > deadline:
                return False
            item = self._inbox.recv(0.05)
            if item is not None:
                self._take(item[1])
        return True

    def close(self) -> None:
        self._inbox.close()


def wait_until_alive(session: zenoh.Session, keys: Keys, components: tuple[str, ...], *, timeout_s: float,
                     stop: threading.Event | None = None) -> bool:
    """Wait until every component's liveliness token is visible (False on timeout or ``stop``)."""
    deadline = time.monotonic() + timeout_s
    while True:
        alive = {str(r.ok.key_expr) for r in session.liveliness().get(keys.status("*"), timeout=1.0)
                 if r.ok is not None}
        if all(keys.status(c) in alive for c in components):
            return True
        if (stop is not None and stop.is_set()) or time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def wait_until_matched(publishers, *, timeout_s: float, stop: threading.Event | None = None) -> bool:
    """Wait until every publisher has at least one matching subscriber."""
    deadline = time.monotonic() + timeout_s
    while not all(p.matching_status.matching for p in publishers):
        if (stop is not None and stop.is_set()) or time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


class StatusReporter:
    """Liveliness token + a StatusMessage every ``period_s`` on ``status/<component>``.

    Call :meth:`tick` from the worker loop (no thread); ``counters`` are totals, ``fps`` is computed
    from the ``processed`` counter between reports, ``latency_ms`` is the mean of :meth:`latency` calls.
    """

    def __init__(self, session: zenoh.Session, keys: Keys, component: str, *, period_s: float = 1.0,
                 clock: Callable[[], float] = time.monotonic, wall_ns: Callable[[], int] = time.time_ns) -> None:
        self.component = check_name(component, "component")
        self.key = keys.status(self.component)
        self._token = session.liveliness().declare_token(self.key)
        self._pub = session.declare_publisher(self.key)
        self.period_s, self._clock, self._wall_ns = period_s, clock, wall_ns
        self.counters: dict[str, float] = collections.defaultdict(float)
        self._lat: list[float] = []
        self._last_t = clock()
        self._last_processed = 0.0

    def count(self, name: str, n: float = 1) -> None:
        """Add ``n`` to counter ``name``."""
        self.counters[name] += n

    def latency(self, ms: float) -> None:
        """Record one latency (milliseconds); the next status reports their mean."""
        self._lat.append(float(ms))

    def tick(self, *, state: str = "running", force: bool = False, **gauges: float) -> StatusMessage | None:
        """Publish a status once ``period_s`` passed since the last (always when ``force``).

        Parameters
        ----------
        state : str
            ``"running"``, ``"finished"`` or ``"failed"``.
        force : bool
            Publish now regardless of the period.
        **gauges : float
            Current values reported beside the counters (queue depths, cameras present, ...).

        Returns
        -------
        StatusMessage or None
            What was published (counters, ``fps`` of ``processed`` since the last status,
            mean ``latency_ms``, gauges), or None if it was not time yet.
        """
        now = self._clock()
        dt = now - self._last_t
        if dt < self.period_s and not force:
            return None
        processed = self.counters.get("processed", 0.0)
        stats = dict(self.counters)
        stats["fps"] = (processed - self._last_processed) / dt if dt > 0 else 0.0
        if self._lat:
            stats["latency_ms"] = sum(self._lat) / len(self._lat)
        stats.update({k: float(v) for k, v in gauges.items()})
        msg = StatusMessage(self.component, state, self._wall_ns(), stats)
        self._pub.put(msg.to_bytes())
        self._last_t, self._last_processed, self._lat = now, processed, []
        return msg

    def close(self) -> None:
        """Withdraw the status publisher and the liveliness token."""
        for obj in (self._pub, self._token):
            try:
                obj.undeclare()
            except Exception:
                pass
