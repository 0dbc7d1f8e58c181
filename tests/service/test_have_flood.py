"""A flood of have notices costs the track worker no decoding beyond each camera's rate limit: the
notices over it are dropped before they are parsed (bench/hostile.py's attack sent 1 000 a second on
one camera's key, each a JSON parse and validation in the worker that fits)."""

from __future__ import annotations

import time

import pytest

from service.flow.window import KeyedRateLimit
from service.wire.bus import Inbox, Keys, ZenohSettings, free_port, open_session
from service.wire.records import HaveMessage


def test_keyed_rate_limit_keeps_named_keys_apart_and_others_shared():
    lim = KeyedRateLimit(10.0, 4, ["a", "b"])
    assert sum(lim.allow("a", 0.0) for _ in range(100)) == 4  # a flood on a: its burst only
    assert all(lim.allow("b", 0.0) for _ in range(4))  # b's budget untouched
    assert sum(lim.allow(f"x{i}", 0.0) for i in range(10_000)) == 4  # invented keys: one shared bucket
    assert lim.limited == 96 + 9_996 and len(lim._limits) == 2
    assert lim.allow("a", 0.1)  # refills at rate_hz


@pytest.fixture
def pair():
    port = free_port()
    a = open_session(ZenohSettings.loopback(port, listen=True))
    b = open_session(ZenohSettings.loopback(port, listen=False))
    yield a, b
    b.close()
    a.close()


def test_inbox_drops_a_flood_before_decoding_it(pair):
    a, b = pair
    keys = Keys("flood")
    decoded = []

    def decode(data: bytes) -> HaveMessage:
        decoded.append(len(data))
        return HaveMessage.from_bytes(data)

    lim = KeyedRateLimit(200.0, 64, [keys.have("cam0"), keys.have("cam1")])
    inbox = Inbox(b, keys.have("*"), decode, depth=8, latest_per_key=True, admit=lambda k: lim.allow(k, 0.0))
    time.sleep(0.3)  # the subscription reaches the other session
    for k in range(1000):
        a.put(keys.have("cam1"), HaveMessage("cam1", (k,)).to_bytes())
    for k in range(5):
        a.put(keys.have("cam0"), HaveMessage("cam0", (k,)).to_bytes())
    deadline = time.monotonic() + 5.0
    while inbox.received + inbox.limited < 1005 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert inbox.received + inbox.limited == 1005
    assert len(decoded) == inbox.received == 64 + 5 and inbox.limited == 1000 - 64
    got = {r.key: r.message for r in inbox.drain()}
    assert got[keys.have("cam0")].frame_ids == (4,)  # the other camera's notices all came through
    inbox.close()
