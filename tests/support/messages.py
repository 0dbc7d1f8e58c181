"""Byte-level mutations of a valid wire message, for the fuzz tests of every decoder."""

from __future__ import annotations

import struct

import numpy as np

from service.wire.messages import HEADER


def mutations(data: bytes, rng: np.random.Generator):
    n = len(data)
    yield rng.bytes(int(rng.integers(0, 64)))
    yield data[: int(rng.integers(0, n))]
    flipped = bytearray(data)
    for i in rng.integers(0, n, size=int(rng.integers(1, 8))):
        flipped[i] ^= 1 << int(rng.integers(0, 8))
    yield bytes(flipped)
    yield data + rng.bytes(int(rng.integers(1, 16)))
    # header with huge/odd declared lengths
    if n >= HEADER.size:
        yield data[:8] + struct.pack("<II", int(rng.integers(0, 2**32)), int(rng.integers(0, 2**32))) + data[16:]
    # corrupted JSON objects
    yield data.replace(b'"', b"'", 1)
    yield b"[" * 100_000 + b"]" * 100_000

