"""A fake trigger box behind pyusb's real backend interface (``usb.backend.IBackend``).

``FakeTriggerBackend`` simulates protocol v1 the way the reference firmware (deploy/trigger/firmware) does, on an
injected device clock, and logs every control transfer so the tests can assert the bytes on the wire.
"""

from __future__ import annotations

import errno
import struct
from types import SimpleNamespace

import usb.backend
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core

from capture.trigger import (
    PRODUCT_ID,
    VENDOR_ID,
)

HOST_OFFSET_NS = 7_000_000_123  # host_ns = device_us * 1000 + HOST_OFFSET_NS in these tests


class FakeBox:
    """Device state of one simulated trigger box (device clock in µs)."""

    def __init__(self, *, serial="TB0001", vid=VENDOR_ID, pid=PRODUCT_ID, magic=b"CCTB", protocol=1, clock_us=None):
        self.now_us = 1_000_000 if clock_us is None else clock_us
        self.serial, self.magic, self.protocol = serial, magic, protocol
        self.period_us, self.width_us = 33_333, 1000
        self.t_start_us: int | None = None
        self.limit: int | None = None
        self.stopped_count: int | None = None
        self.unplugged_errno: int | None = None
        self.open_errno: int | None = None
        self.stall: set[int] = set()
        self.short_reply: set[int] = set()
        self.descriptor = SimpleNamespace(
            bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0xFF, bDeviceSubClass=0, bDeviceProtocol=0,
            bMaxPacketSize0=64, idVendor=vid, idProduct=pid, bcdDevice=0x0100, iManufacturer=0, iProduct=0,
            iSerialNumber=3 if serial else 0, bNumConfigurations=1, address=5, bus=1, port_number=2,
            port_numbers=(2,), speed=2,
        )

    def count(self) -> int:
        if self.t_start_us is None or self.now_us < self.t_start_us:
            return 0
        c = (self.now_us - self.t_start_us) // self.period_us + 1
        for cap in (self.limit, self.stopped_count):
            if cap is not None:
                c = min(c, cap)
        return c

    def handle(self, rtype, req, data) -> bytes | int:
        """Firmware behaviour: returns the IN reply or the OUT byte count; raises USBError on STALL."""
        if req in self.stall:
            raise usb.core.USBError("Pipe error", errno=errno.EPIPE)
        if rtype == 0x80 and req == 0x06:  # standard GET_DESCRIPTOR(string)
            return b"\x04\x03\x09\x04" if data == 0 else bytes([2 + 2 * len(self.serial), 3]) + self.serial.encode("utf-16-le")
        if rtype == 0xC0:
            if req == 0x01:
                out = struct.pack("<4sBBBB", self.magic, self.protocol, 1, 2, 4)
            elif req == 0x06:
                c = self.count()
                running = self.t_start_us is not None and self.stopped_count is None and (self.limit is None or c < self.limit)
                flags = int(running) | (2 if running and self.limit is not None else 0)
                last = self.t_start_us + (c - 1) * self.period_us if c else 0
                out = struct.pack("<IIQ", c, flags, last)
            elif req == 0x07:
                out = struct.pack("<Q", self.now_us)
            else:
                raise usb.core.USBError("Pipe error", errno=errno.EPIPE)
            return out[:-2] if req in self.short_reply else out
        payload = bytes(data)
        if req == 0x02 and len(payload) == 8:
            period, width = struct.unpack("<II", payload)
            if period < 1000 or not 1 <= width < period:
                raise usb.core.USBError("Pipe error", errno=errno.EPIPE)
            self.period_us, self.width_us = period, width
        elif req == 0x03 and not payload:
            self.t_start_us, self.limit, self.stopped_count = self.now_us, None, None
        elif req == 0x04 and not payload:
            self.stopped_count = self.count()
        elif req == 0x05 and len(payload) == 4:
            self.t_start_us, self.limit, self.stopped_count = self.now_us, struct.unpack("<I", payload)[0], None
        else:
            raise usb.core.USBError("Pipe error", errno=errno.EPIPE)
        return len(payload)


class FakeTriggerBackend(usb.backend.IBackend):
    """A pyusb backend whose bus holds the given fake devices."""

    def __init__(self, *boxes: FakeBox):
        self.boxes = list(boxes)
        self.log: list[tuple] = []

    def enumerate_devices(self):
        return iter(self.boxes)

    def get_device_descriptor(self, dev):
        return dev.descriptor

    def get_configuration_descriptor(self, dev, config):
        return SimpleNamespace(bLength=9, bDescriptorType=2, wTotalLength=18, bNumInterfaces=1, bConfigurationValue=1,
                               iConfiguration=0, bmAttributes=0x80, bMaxPower=50, extra_descriptors=[])

    def open_device(self, dev):
        if dev.open_errno is not None:
            raise usb.core.USBError("Access denied", errno=dev.open_errno)
        return dev

    def close_device(self, dev_handle):
        pass

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        box = dev_handle
        if box.unplugged_errno is not None:
            raise usb.core.USBError("No such device (it may have been disconnected)", errno=box.unplugged_errno)
        is_in = bool(bmRequestType & 0x80)
        self.log.append((bmRequestType, bRequest, wValue, wIndex, len(data) if is_in else bytes(data)))
        reply = box.handle(bmRequestType, bRequest, (wValue & 0xFF) if bmRequestType == 0x80 else data)
        if not is_in:
            return reply
        n = min(len(reply), len(data))
        data[:n] = type(data)("B", reply[:n])
        return n


def host_clock(box: FakeBox):
    return lambda: box.now_us * 1000 + HOST_OFFSET_NS

