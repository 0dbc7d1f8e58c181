"""Hardware trigger box (pyusb) and a software trigger with the same interface.

The box is a small USB device (RP2040 / Arduino class) that drives TTL pulses
into the cameras' trigger inputs; pulse ``k`` (from 0 after START/ARM) exposes
frame ``k`` of every camera, so the pulse counter *is* the frame id.

USB identity: VID ``0x1209`` (pid.codes, open-source hardware), PID
``0x0001`` — a pid.codes **test** PID, fine for development and in-house
boxes; a box that is distributed must request its own PID from pid.codes.
``deploy/udev/99-contourcap-trigger.rules`` gives non-root access.

Vendor protocol v1 (also ``deploy/trigger/PROTOCOL.md``).  Control transfers
on endpoint 0, recipient device, wIndex = 0; OUT = bmRequestType ``0x40``,
IN = ``0xC0``; all multi-byte fields little-endian (``struct`` formats)::

    bRequest      dir  wValue  data (struct)                  meaning
    0x01 INFO     IN   0       "<4sBBBB" 8 B: magic b"CCTB",  identify: protocol version,
                                protocol, fw_major,           firmware version, number of
                                fw_minor, n_outputs           trigger outputs
    0x02 RATE     OUT  0       "<II" 8 B: period_us,          pulse period and high time, µs
                                width_us                      (1000 <= period, 1 <= width < period)
    0x03 START    OUT  0       none                           counter := 0, pulse free-running
    0x04 STOP     OUT  0       none                           stop after the current pulse
    0x05 ARM      OUT  0       "<I" 4 B: n_pulses             counter := 0, emit n pulses, stop
    0x06 COUNTER  IN   0       "<IIQ" 16 B: count, flags,     pulses since START/ARM; flags bit0
                                last_pulse_us                 running, bit1 armed; device µs time
                                                              of the last pulse's rising edge
    0x07 TIME     IN   0       "<Q" 8 B: now_us               device µs clock (for clock offset)

A request the firmware cannot honour (bad length, out-of-range rate) is
answered with a STALL (pyusb: ``USBError`` errno ``EPIPE``).

Frame-id mapping: after ``read_counter()``, the last pulse has frame id
``count - 1``; ``sync_clock()`` measures host - device clock offset (TIME at
the midpoint of the round trip).  ``refresh()`` does both and anchors
``frame_id_at(host_ns)``, which maps a host timestamp (e.g. a
software-timestamped camera frame, minus its transfer latency
``latency_ns``) to the id of the latest pulse at or before it.  Refresh
every few seconds in a live capture (clock drift).

``SoftwareTrigger`` has the same methods on an injected clock, for cameras
without a trigger input: its "pulses" are a time grid that ``frame_id_at``
quantises frame timestamps to.
"""

from __future__ import annotations

import errno
import math
import struct
import threading
import time
from dataclasses import dataclass
from typing import Callable, Protocol

import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core
import usb.util

from capture.errors import CaptureError

__all__ = [
    "VENDOR_ID",
    "PRODUCT_ID",
    "PROTOCOL_VERSION",
    "Request",
    "TriggerError",
    "UsbUnavailableError",
    "TriggerNotFoundError",
    "TriggerDisconnectedError",
    "TriggerProtocolError",
    "TriggerInfo",
    "PulseCounter",
    "Trigger",
    "TriggerBox",
    "SoftwareTrigger",
    "start_trigger_box",
]

VENDOR_ID = 0x1209
PRODUCT_ID = 0x0001
PROTOCOL_VERSION = 1
MAGIC = b"CCTB"
REQ_OUT = 0x40  # host -> device, vendor, device recipient
REQ_IN = 0xC0  # device -> host, vendor, device recipient
INFO_FMT, RATE_FMT, ARM_FMT, COUNTER_FMT, TIME_FMT = "<4sBBBB", "<II", "<I", "<IIQ", "<Q"
FLAG_RUNNING, FLAG_ARMED = 1, 2
MIN_PERIOD_US = 1000


class Request:
    """bRequest codes of protocol v1."""

    INFO = 0x01
    RATE = 0x02
    START = 0x03
    STOP = 0x04
    ARM = 0x05
    COUNTER = 0x06
    TIME = 0x07


class TriggerError(CaptureError):
    """Base class of trigger errors."""


class UsbUnavailableError(TriggerError):
    """No libusb (or other pyusb backend) is installed."""


class TriggerNotFoundError(TriggerError):
    """No trigger box with the VID/PID (and serial) is plugged in."""


class TriggerDisconnectedError(TriggerError):
    """The box went away during a session (unplugged, reset)."""


class TriggerProtocolError(TriggerError):
    """The device answered something protocol v1 does not allow."""


@dataclass(frozen=True)
class TriggerInfo:
    """What a box says about itself: protocol version, firmware (major, minor), output count, serial."""

    protocol: int
    firmware: tuple[int, int]
    outputs: int
    serial: str | None = None


@dataclass(frozen=True)
class PulseCounter:
    """Counter state: ``count`` pulses since START/ARM; the last has frame id ``count - 1``.

    ``last_pulse_us`` is on the device clock (µs); ``-1`` frame id = no pulse yet.
    """

    count: int
    running: bool
    armed: bool
    last_pulse_us: int

    @property
    def last_frame_id(self) -> int:
        return self.count - 1


class Trigger(Protocol):
    """What the capture side uses of a trigger (box or software)."""

    def set_rate(self, fps: float, *, pulse_width_us: int | None = None) -> None: ...
    def start(self) -> None: ...
    def stop(self) -> None: ...
    def arm(self, n_pulses: int) -> None: ...
    def read_counter(self) -> PulseCounter: ...
    def frame_id_at(self, timestamp_ns: int, *, latency_ns: int = 0) -> int: ...
    def refresh(self) -> tuple[int, int]: ...
    def close(self) -> None: ...


def _period_us(fps: float) -> int:
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and 0 < fps <= 1e6 / MIN_PERIOD_US):
        raise ValueError(f"fps must be in (0, {1e6 / MIN_PERIOD_US:g}], got {fps!r}")
    return int(round(1e6 / fps))


def _default_backend(find_library):
    for module in (usb.backend.libusb1, usb.backend.libusb0, usb.backend.openusb):
        backend = module.get_backend(find_library=find_library)
        if backend is not None:
            return backend
    raise UsbUnavailableError(
        "no USB backend: install libusb-1.0 (Debian/Ubuntu: apt install libusb-1.0-0; macOS: brew install libusb)"
    )


class TriggerBox:
    """Driver of the USB trigger box (protocol in the module docstring).

    Use ``TriggerBox.find()``; the box is a context manager.  ``clock`` is the
    host nanosecond clock used by ``sync_clock`` (``time.monotonic_ns``).
    """

    def __init__(self, device, *, clock: Callable[[], int] = time.monotonic_ns, timeout_ms: int = 500):
        self._dev = device
        self._clock = clock
        self.timeout_ms = int(timeout_ms)
        self.period_us: int | None = None
        self._offset_ns: int | None = None  # host_ns - device_us * 1000
        self._anchor: tuple[int, int] | None = None  # (frame id, host ns) of the last pulse at refresh()
        self.info = self._identify()

    @classmethod
    def find(
        cls,
        *,
        vid: int = VENDOR_ID,
        pid: int = PRODUCT_ID,
        serial: str | None = None,
        backend=None,
        find_library=None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> "TriggerBox":
        """Open the first box with ``vid:pid`` (and ``serial`` if given).

        Raises ``UsbUnavailableError`` without libusb, ``TriggerNotFoundError``
        when no such device is plugged in (or readable: see the udev rule).
        """
        if backend is None:
            backend = _default_backend(find_library)
        try:
            devices = list(usb.core.find(find_all=True, idVendor=vid, idProduct=pid, backend=backend))
        except usb.core.NoBackendError as exc:
            raise UsbUnavailableError(f"no USB backend: {exc}") from None
        where = f"trigger box {vid:04x}:{pid:04x}"
        for dev in devices:
            if serial is not None:
                try:
                    if dev.serial_number != serial:
                        continue
                except (usb.core.USBError, ValueError) as exc:
                    raise TriggerNotFoundError(f"{where}: cannot read serial number ({exc}); check permissions (udev rule)") from None
            return cls(dev, clock=clock)
        wanted = f" with serial {serial!r}" if serial else ""
        raise TriggerNotFoundError(
            f"{where}{wanted} not found ({len(devices)} with that VID:PID present); is it plugged in, and is "
            "deploy/udev/99-contourcap-trigger.rules installed?"
        )

    def __enter__(self) -> "TriggerBox":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._dev is not None:
            try:
                usb.util.dispose_resources(self._dev)
            except usb.core.USBError:
                pass
            self._dev = None

    # transport -----------------------------------------------------------
    def _transfer(self, request_type: int, request: int, data_or_length, name: str):
        if self._dev is None:
            raise TriggerError(f"trigger box: {name} on a closed device")
        try:
            return self._dev.ctrl_transfer(request_type, request, 0, 0, data_or_length, self.timeout_ms)
        except usb.core.USBError as exc:
            if exc.errno in (errno.ENODEV, errno.ENOENT, errno.ESHUTDOWN):
                raise TriggerDisconnectedError(f"trigger box disconnected during {name}: {exc}") from None
            if exc.errno == errno.EACCES:
                raise TriggerError(f"trigger box: permission denied on {name}; install deploy/udev/99-contourcap-trigger.rules") from None
            if exc.errno == errno.EPIPE:
                raise TriggerProtocolError(f"trigger box refused {name} (STALL): {exc}") from None
            raise TriggerError(f"trigger box: {name} failed: {exc}") from None

    def _out(self, request: int, payload: bytes, name: str) -> None:
        sent = self._transfer(REQ_OUT, request, payload, name)
        if sent != len(payload):
            raise TriggerProtocolError(f"trigger box: {name} sent {sent} of {len(payload)} bytes")

    def _in(self, request: int, fmt: str, name: str) -> tuple:
        size = struct.calcsize(fmt)
        data = bytes(self._transfer(REQ_IN, request, size, name))
        if len(data) != size:
            raise TriggerProtocolError(f"trigger box: {name} reply has {len(data)} bytes, expected {size}")
        return struct.unpack(fmt, data)

    # protocol ------------------------------------------------------------
    def _identify(self) -> TriggerInfo:
        magic, protocol, major, minor, outputs = self._in(Request.INFO, INFO_FMT, "INFO")
        if magic != MAGIC:
            raise TriggerProtocolError(f"trigger box: INFO magic {magic!r}, expected {MAGIC!r} (not a contourcap trigger box?)")
        if protocol != PROTOCOL_VERSION:
            raise TriggerProtocolError(f"trigger box speaks protocol v{protocol}; this driver speaks v{PROTOCOL_VERSION}")
        serial = None
        if getattr(self._dev, "iSerialNumber", 0):
            try:
                serial = self._dev.serial_number
            except (usb.core.USBError, ValueError):
                serial = None
        return TriggerInfo(protocol, (major, minor), outputs, serial)

    def set_rate(self, fps: float, *, pulse_width_us: int | None = None) -> None:
        """Pulse rate; width defaults to a quarter period (at most 1 ms)."""
        period = _period_us(fps)
        width = min(period // 4, 1000) if pulse_width_us is None else int(pulse_width_us)
        if not 1 <= width < period:
            raise ValueError(f"pulse_width_us must be in [1, {period}) for {fps} fps, got {width}")
        self._out(Request.RATE, struct.pack(RATE_FMT, period, width), "RATE")
        self.period_us = period

    def start(self) -> None:
        """Start pulsing (free-running) and reset the pulse counter."""
        self._out(Request.START, b"", "START")

    def stop(self) -> None:
        """Stop pulsing."""
        self._out(Request.STOP, b"", "STOP")

    def arm(self, n_pulses: int) -> None:
        """Emit exactly ``n_pulses`` pulses at the set rate, then stop."""
        if not 1 <= int(n_pulses) < 2**32:
            raise ValueError(f"n_pulses must be in [1, 2**32), got {n_pulses}")
        self._out(Request.ARM, struct.pack(ARM_FMT, int(n_pulses)), "ARM")

    def read_counter(self) -> PulseCounter:
        count, flags, last_us = self._in(Request.COUNTER, COUNTER_FMT, "COUNTER")
        return PulseCounter(count, bool(flags & FLAG_RUNNING), bool(flags & FLAG_ARMED), last_us)

    def device_time_us(self) -> int:
        return self._in(Request.TIME, TIME_FMT, "TIME")[0]

    def sync_clock(self) -> int:
        """Measure and keep ``host_ns - device_us * 1000`` (round-trip midpoint); returns it."""
        before = self._clock()
        device_us = self.device_time_us()
        after = self._clock()
        self._offset_ns = (before + after) // 2 - device_us * 1000
        return self._offset_ns

    def refresh(self) -> tuple[int, int]:
        """``read_counter`` + ``sync_clock`` and re-anchor ``frame_id_at``; returns ``(frame_id, host_ns)`` of the last pulse.

        Call every few seconds during a live capture (e.g. from a timer thread):
        crystal drift (~50 ppm) moves the extrapolation ~1 ms per 20 s otherwise.
        """
        counter = self.read_counter()
        offset = self.sync_clock()
        if counter.count == 0:
            raise TriggerError("trigger box: no pulse yet (set_rate() and start() first)")
        self._anchor = (counter.last_frame_id, offset + counter.last_pulse_us * 1000)
        return self._anchor

    def frame_id_at(self, timestamp_ns: int, *, latency_ns: int = 0) -> int:
        """Frame id of the latest pulse at or before host time ``timestamp_ns - latency_ns``.

        Extrapolates from the anchor of the last ``refresh()`` at the set rate
        (safe to call from camera threads while another thread refreshes).
        """
        anchor = self._anchor
        if self.period_us is None or anchor is None:
            raise TriggerError("trigger box: frame_id_at needs set_rate(), start() and refresh()")
        last_id, last_host_ns = anchor
        k = math.floor((timestamp_ns - latency_ns - last_host_ns) / (self.period_us * 1000))
        return max(last_id + k, 0)


class SoftwareTrigger:
    """A trigger-shaped time grid on an injected clock (no hardware).

    After ``start()`` at clock time ``t0``, pulse ``k`` happens at
    ``t0 + k * period``; ``arm(n)`` stops the grid after ``n`` pulses.
    """

    def __init__(self, *, clock: Callable[[], int] = time.monotonic_ns, fps: float = 30.0):
        self._clock = clock
        self.period_us = _period_us(fps)
        self._t0: int | None = None
        self._limit: int | None = None
        self._stopped_count: int | None = None
        self.info = TriggerInfo(PROTOCOL_VERSION, (0, 0), 0, "software")

    def set_rate(self, fps: float, *, pulse_width_us: int | None = None) -> None:
        """Pulse rate (frames per second); the width is ignored."""
        self.period_us = _period_us(fps)

    def start(self) -> None:
        """Count pulses from now on the injected clock."""
        self._t0, self._limit, self._stopped_count = self._clock(), None, None

    def arm(self, n_pulses: int) -> None:
        """Start, and stop counting after ``n_pulses`` pulses."""
        if not 1 <= int(n_pulses) < 2**32:
            raise ValueError(f"n_pulses must be in [1, 2**32), got {n_pulses}")
        self.start()
        self._limit = int(n_pulses)

    def stop(self) -> None:
        if self._t0 is not None and self._stopped_count is None:
            self._stopped_count = self._count(self._clock())

    def _count(self, now_ns: int) -> int:
        if self._t0 is None or now_ns < self._t0:
            return 0
        count = (now_ns - self._t0) // (self.period_us * 1000) + 1
        if self._limit is not None:
            count = min(count, self._limit)
        if self._stopped_count is not None:
            count = min(count, self._stopped_count)
        return int(count)

    def read_counter(self) -> PulseCounter:
        now = self._clock()
        count = self._count(now)
        running = self._t0 is not None and self._stopped_count is None and (self._limit is None or count < self._limit)
        last_us = (self._t0 + (count - 1) * self.period_us * 1000) // 1000 if count else 0
        return PulseCounter(count, running, self._limit is not None and running, last_us)

    def refresh(self) -> tuple[int, int]:
        """Same shape as ``TriggerBox.refresh``: ``(frame_id, host_ns)`` of the last pulse (nothing to re-sync)."""
        if self._t0 is None:
            raise TriggerError("software trigger: refresh before start()")
        c = self.read_counter()
        if c.count == 0:
            raise TriggerError("software trigger: no pulse yet")
        return c.last_frame_id, self._t0 + c.last_frame_id * self.period_us * 1000

    def frame_id_at(self, timestamp_ns: int, *, latency_ns: int = 0) -> int:
        """Id of the latest pulse at or before ``timestamp_ns - latency_ns`` (clock ns)."""
        if self._t0 is None:
            raise TriggerError("software trigger: frame_id_at before start()")
        return max(int((timestamp_ns - latency_ns - self._t0) // (self.period_us * 1000)), 0)

    def close(self) -> None:
        self._t0 = None


def start_trigger_box(fps: float, *, stop: threading.Event, resync_s: float = 2.0,
                      on_lost: Callable[[TriggerError], None] | None = None, backend=None,
                      clock: Callable[[], int] | None = None) -> TriggerBox:
    """Open the USB trigger box, run it at ``fps`` and keep its clock anchored.

    The box is started, given two periods to pulse, and its clock anchored (``refresh``); a
    daemon thread re-anchors it every ``resync_s`` until ``stop`` is set.  A box lost later
    calls ``on_lost(error)`` and sets ``stop``.

    Parameters
    ----------
    fps : float
        Pulse rate (pulses per second).
    stop : threading.Event
        Ends the re-anchoring thread; set by it when the box is lost.
    resync_s : float
        Seconds between re-anchorings.
    on_lost : callable (TriggerError) -> None, optional
        Told why the box was lost (from the re-anchoring thread).
    backend : pyusb backend, optional
        For tests (a fake device).
    clock : callable () -> int, optional
        Host nanosecond clock the box's pulses are mapped to (default ``time.monotonic_ns``).

    Returns
    -------
    TriggerBox
        Running; the caller stops and closes it.  ``TriggerError`` if the box is absent or fails
        to start (it is closed first).
    """
    box = TriggerBox.find(backend=backend, **({} if clock is None else {"clock": clock}))
    try:
        box.set_rate(fps)
        box.start()
        time.sleep(2.0 / fps)
        box.refresh()
    except BaseException:
        box.close()  # the caller never sees this box: release the device here
        raise

    def resync() -> None:
        while not stop.wait(resync_s):
            try:
                box.refresh()
            except TriggerError as exc:
                if on_lost is not None:
                    on_lost(exc)
                stop.set()
                return

    threading.Thread(target=resync, name="trigger-resync", daemon=True).start()
    return box
