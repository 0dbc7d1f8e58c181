"""Trigger box driver through pyusb's real code path, on a fake device behind ``usb.backend.IBackend``.

``FakeTriggerBackend`` simulates protocol v1 the way the reference firmware
(deploy/trigger/firmware) does, on an injected device clock, and logs every
control transfer so the tests can assert the bytes on the wire.
"""

from __future__ import annotations

import errno

import numpy as np
import pytest
import usb.backend
import usb.backend.libusb0
import usb.backend.libusb1
import usb.backend.openusb
import usb.core

from capture.trigger import (
    SoftwareTrigger,
    TriggerBox,
    TriggerDisconnectedError,
    TriggerError,
    TriggerNotFoundError,
    TriggerProtocolError,
    UsbUnavailableError,
)
from tests.support.trigger import HOST_OFFSET_NS, FakeBox, FakeTriggerBackend, host_clock  # noqa: F401


@pytest.fixture
def rig():
    box = FakeBox()
    backend = FakeTriggerBackend(box)
    return box, backend, TriggerBox.find(backend=backend, clock=host_clock(box))


def test_identify_bytes_and_info(rig):
    box, backend, tb = rig
    assert backend.log[0] == (0xC0, 0x01, 0, 0, 8)
    assert tb.info.protocol == 1 and tb.info.firmware == (1, 2) and tb.info.outputs == 4
    assert tb.info.serial == "TB0001"


def test_out_requests_on_the_wire(rig):
    _, backend, tb = rig
    backend.log.clear()
    tb.set_rate(50)
    tb.start()
    tb.stop()
    tb.arm(100)
    tb.set_rate(120, pulse_width_us=200)
    assert backend.log == [
        (0x40, 0x02, 0, 0, bytes.fromhex("204e0000" "e8030000")),  # period 20000 us, width 1000 us
        (0x40, 0x03, 0, 0, b""),
        (0x40, 0x04, 0, 0, b""),
        (0x40, 0x05, 0, 0, bytes.fromhex("64000000")),
        (0x40, 0x02, 0, 0, bytes.fromhex("8d200000" "c8000000")),  # 8333 us, 200 us
    ]
    with pytest.raises(ValueError, match="pulse_width_us"):
        tb.set_rate(50, pulse_width_us=20000)
    with pytest.raises(ValueError, match="fps"):
        tb.set_rate(0)
    assert len(backend.log) == 5  # nothing sent for rejected arguments


def test_counter_and_frame_ids(rig):
    box, backend, tb = rig
    tb.set_rate(50)
    tb.start()
    t0_us = box.now_us
    box.now_us += 95_000  # pulses at 0, 20, 40, 60, 80 ms
    backend.log.clear()
    c = tb.read_counter()
    assert backend.log == [(0xC0, 0x06, 0, 0, 16)]
    assert (c.count, c.last_frame_id, c.running, c.armed, c.last_pulse_us) == (5, 4, True, False, t0_us + 80_000)
    assert tb.sync_clock() == HOST_OFFSET_NS
    with pytest.raises(TriggerError, match="refresh"):
        tb.frame_id_at(0)
    assert tb.refresh() == (4, (t0_us + 80_000) * 1000 + HOST_OFFSET_NS)
    host_t0 = t0_us * 1000 + HOST_OFFSET_NS
    ms = 1_000_000
    assert tb.frame_id_at(host_t0 + 80 * ms) == 4
    assert tb.frame_id_at(host_t0 + 99 * ms) == 4
    assert tb.frame_id_at(host_t0 + 100 * ms) == 5  # a pulse after the counter read
    assert tb.frame_id_at(host_t0 + 45 * ms) == 2
    assert tb.frame_id_at(host_t0 + 45 * ms, latency_ns=10 * ms) == 1
    assert tb.frame_id_at(host_t0 - 500 * ms) == 0


def test_refresh_follows_clock_drift(rig):
    """The device crystal runs 100 ppm fast: without re-anchoring, ids drift; refresh() fixes them."""
    box, _, tb = rig
    host_ns = [box.now_us * 1000 + HOST_OFFSET_NS]
    tb._clock = lambda: host_ns[0]
    tb.set_rate(50)
    tb.start()
    t0_host = host_ns[0]

    def advance_host(seconds):
        host_ns[0] += int(seconds * 1e9)
        box.now_us = box.now_us + int(seconds * 1e6 * (1 + 100e-6))  # device clock fast by 100 ppm

    advance_host(0.005)
    tb.refresh()
    advance_host(300.0)  # 5 minutes: the box is now 30 ms = 1.5 periods ahead of the nominal grid
    probe = host_ns[0] - 5_000_000  # a frame stamped 5 ms ago (host time)
    truth = int(np.floor((probe - t0_host) * (1 + 100e-6) / 20e6))  # the box's pulse at or before it
    assert truth == 15001
    assert tb.frame_id_at(probe) == truth - 1  # stale anchor: wrong id
    tb.refresh()
    assert tb.frame_id_at(probe) == truth


def test_arm_stops_after_n_pulses(rig):
    box, _, tb = rig
    tb.set_rate(100)
    tb.arm(3)
    box.now_us += 5_000
    c = tb.read_counter()
    assert (c.count, c.running, c.armed) == (1, True, True)
    box.now_us += 1_000_000
    c = tb.read_counter()
    assert (c.count, c.running, c.armed) == (3, False, False)


@pytest.mark.parametrize("code", [errno.ENODEV, errno.ENOENT])
def test_unplugged_mid_session(rig, code):
    box, _, tb = rig
    tb.set_rate(50)
    tb.start()
    box.unplugged_errno = code
    with pytest.raises(TriggerDisconnectedError, match="COUNTER"):
        tb.read_counter()
    with pytest.raises(TriggerDisconnectedError, match="STOP"):
        tb.stop()


def test_not_found_and_serial_selection():
    with pytest.raises(TriggerNotFoundError, match="1209:0001"):
        TriggerBox.find(backend=FakeTriggerBackend())
    with pytest.raises(TriggerNotFoundError, match="udev"):
        TriggerBox.find(backend=FakeTriggerBackend(FakeBox(vid=0x1234)))
    a, b = FakeBox(serial="A1"), FakeBox(serial="B2")
    backend = FakeTriggerBackend(a, b)
    assert TriggerBox.find(backend=backend, serial="B2").info.serial == "B2"
    with pytest.raises(TriggerNotFoundError, match="'C3'"):
        TriggerBox.find(backend=backend, serial="C3")


def test_protocol_errors():
    with pytest.raises(TriggerProtocolError, match="magic"):
        TriggerBox.find(backend=FakeTriggerBackend(FakeBox(magic=b"XXXX")))
    with pytest.raises(TriggerProtocolError, match="v2"):
        TriggerBox.find(backend=FakeTriggerBackend(FakeBox(protocol=2)))
    box = FakeBox()
    tb = TriggerBox.find(backend=FakeTriggerBackend(box))
    box.short_reply.add(0x06)
    with pytest.raises(TriggerProtocolError, match="14 bytes"):
        tb.read_counter()
    box.stall.add(0x03)
    with pytest.raises(TriggerProtocolError, match="refused START"):
        tb.start()
    box.short_reply.clear()
    with pytest.raises(TriggerError, match="no pulse yet"):
        tb.refresh()
    tb.close()
    with pytest.raises(TriggerError, match="closed"):
        tb.start()


def test_permission_denied_points_at_udev_rule():
    box = FakeBox(serial=None)
    box.open_errno = errno.EACCES
    with pytest.raises(TriggerError, match="udev"):
        TriggerBox.find(backend=FakeTriggerBackend(box))


def test_missing_libusb_reported():
    modules = (usb.backend.libusb1, usb.backend.libusb0, usb.backend.openusb)
    if any(getattr(m, "_lib_object", None) is not None or getattr(m, "_lib", None) is not None for m in modules):
        pytest.skip("a libusb backend is already loaded in this process")
    with pytest.raises(UsbUnavailableError, match="libusb"):
        TriggerBox.find(find_library=lambda name: None)


def test_software_trigger_same_interface():
    now = [10_000_000_000]
    trig = SoftwareTrigger(clock=lambda: now[0], fps=50)
    assert trig.read_counter().count == 0
    with pytest.raises(TriggerError, match="before start"):
        trig.frame_id_at(now[0])
    with pytest.raises(TriggerError, match="before start"):
        trig.refresh()
    trig.start()
    t0 = now[0]
    now[0] += 95_000_000
    c = trig.read_counter()
    assert (c.count, c.last_frame_id, c.running, c.last_pulse_us) == (5, 4, True, (t0 + 80_000_000) // 1000)
    assert trig.frame_id_at(t0 + 99_000_000) == 4 and trig.frame_id_at(t0 + 100_000_000) == 5
    assert trig.refresh() == (4, t0 + 80_000_000)
    trig.stop()
    now[0] += 1_000_000_000
    assert trig.read_counter().count == 5 and not trig.read_counter().running
    trig.arm(2)
    now[0] += 1_000_000_000
    c = trig.read_counter()
    assert (c.count, c.running) == (2, False)
