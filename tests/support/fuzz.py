"""Hypothesis strategies for the fuzz tests: random bytes, mutations of valid inputs, and JSON/TOML
shaped data with the right keys and the wrong everything else."""

from __future__ import annotations

from hypothesis import strategies as st

__all__ = ["mutated", "json_values", "json_objects", "toml_values", "toml_tables", "hostile_bytes"]


@st.composite
def mutated(draw, seed: bytes, max_ops: int = 4) -> bytes:
    """``seed`` after up to ``max_ops`` random edits: byte flips, cuts, insertions, truncation, repeats."""
    data = bytearray(seed)
    for _ in range(draw(st.integers(1, max_ops))):
        op = draw(st.sampled_from(("flip", "cut", "insert", "truncate", "repeat", "set")))
        n = len(data)
        i = draw(st.integers(0, max(n - 1, 0)))
        if op == "flip" and n:
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and n:
            data[i] = draw(st.sampled_from((0, 0x7F, 0x80, 0xFF, ord('"'), ord("["), ord("\\"), ord("9"))))
        elif op == "cut" and n:
            del data[i:i + draw(st.integers(1, 16))]
        elif op == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif op == "truncate":
            del data[i:]
        elif op == "repeat" and n:
            j = draw(st.integers(i, n))
            data[i:i] = data[i:j][:4096]
    return bytes(data)


def hostile_bytes(seed: bytes) -> st.SearchStrategy[bytes]:
    """Random bytes, or mutations of a valid ``seed``."""
    return st.one_of(st.binary(max_size=256), mutated(seed))


_scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**70), 2**70),
                     st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12))
json_values = st.recursive(_scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                              st.dictionaries(st.text(max_size=8), inner, max_size=5)),
                           max_leaves=20)


def json_objects(keys) -> st.SearchStrategy[dict]:
    """Objects whose keys are mostly the expected ones (``keys``) and whose values are anything."""
    return st.dictionaries(st.one_of(st.sampled_from(list(keys)), st.text(max_size=8)), json_values, max_size=12)


_toml_scalars = st.one_of(st.booleans(), st.integers(-(2**63), 2**63 - 1), st.floats(allow_nan=True),
                          st.text(max_size=12))
toml_values = st.recursive(_toml_scalars, lambda inner: st.lists(inner, max_size=4), max_leaves=12)


def toml_tables(keys) -> st.SearchStrategy[dict]:
    """Tables with mostly the expected ``keys`` and values of any TOML type (nested lists included)."""
    return st.dictionaries(st.one_of(st.sampled_from(list(keys)), st.text(alphabet="abcxyz_", min_size=1, max_size=6)),
                           toml_values, max_size=8)
