"""Fuzzing the BVH reader (issue 16): mutated motion files give a ``BvhError`` or a ``Bvh``, never
another exception.  ``pytest --fuzz-long`` runs 100x more examples."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tracker.errors import TrackerError
from tracker.synthetic.bvh import Bvh, parse_bvh
from tracker.synthetic.synth import bundled_motion
from tests.support.fuzz import hostile_bytes

# the hierarchy and the first frames of the bundled clip: a short, valid seed
_TEXT = bundled_motion("scaled_131_03").read_text()
_HEAD, _MOTION = _TEXT.split("MOTION", 1)
_ROWS = _MOTION.strip().splitlines()
SEED = (_HEAD + "MOTION\nFrames: 3\n" + "\n".join(_ROWS[1:2] + _ROWS[2:5]) + "\n").encode()


@settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=hostile_bytes(SEED))
def test_bvh_reader_raises_only_bvh_error(data):
    try:
        bvh = parse_bvh(data.decode("utf-8", errors="replace"), source="fuzz.bvh")
    except TrackerError:
        return
    assert isinstance(bvh, Bvh)


def test_seed_is_valid():
    assert isinstance(parse_bvh(SEED.decode()), Bvh)
