"""Static scene in the blob tracker's hull (``tracker.blobs.static_voxels``): a block that stays away from
the body becomes scene after the frames its running average needs, a body part never does, and the
tracker then leaves the block out of its fit and of the unexplained volume."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.blobs import learn_blobs
from tracker.blobs.static_voxels import StaticVoxels
from tests.tracker.test_blob_quality import VOXEL_M, _hull_of, _standing, _tracker, model  # noqa: F401

CHAIR = np.array([0.55, -0.15, 0.0])  # a block beside the body: 0.3 × 0.3 × 0.45 m


def _chair() -> np.ndarray:
    g = np.arange(0, 0.3, VOXEL_M) + VOXEL_M / 2
    z = np.arange(0, 0.45, VOXEL_M) + VOXEL_M / 2
    return (np.stack(np.meshgrid(g, g, z, indexing="ij"), -1).reshape(-1, 3) + CHAIR)


def _frames_needed(rate: float, threshold: float) -> int:
    return int(np.ceil(np.log(1 - threshold) / np.log(1 - rate) - 1e-9))


@pytest.mark.parametrize("rate,threshold", [(0.05, 0.7), (0.2, 0.5)])
def test_a_block_away_from_the_body_turns_static_after_its_frames(rate, threshold):
    rng = np.random.default_rng(int(100 * rate))
    block = _chair() + rng.uniform(-0.5, 0.5, 3)
    body = rng.uniform(-0.2, 0.2, (200, 3)) + [0.0, 0.0, 1.0]
    pts = np.vstack([block, body])
    away = np.r_[np.ones(len(block), bool), np.zeros(len(body), bool)]
    sv = StaticVoxels(VOXEL_M, rate=rate, threshold=threshold)
    n = _frames_needed(rate, threshold)
    for _ in range(n - 1):
        sv.update(pts, away)
    assert not sv.static(pts).any()
    sv.update(pts, away)
    s = sv.static(pts)
    assert s[: len(block)].all() and not s[len(block):].any()
    for _ in range(3):  # the body comes back over the block: it stops being scene
        sv.update(pts, np.zeros(len(pts), bool))
    assert not sv.static(block).any()


def test_rejects_bad_options():
    with pytest.raises(ValueError):
        StaticVoxels(0.0)
    with pytest.raises(ValueError):
        StaticVoxels(0.03, rate=0.0)


def test_tracker_stops_counting_a_static_block_as_unexplained(model):  # noqa: F811
    tracker, p = _tracker(model), _standing(model)
    hull = _hull_of(model, p, extra=_chair())
    tracker.blobs = learn_blobs(model, p, hull.centres, hull.sizes, hull.colours)
    _, first = tracker.fit(hull, p)
    o = tracker.options
    assert first["static_fraction"] == 0.0 and first["unexplained"] > 0.2, first
    for _ in range(_frames_needed(o.static_rate, o.static_threshold)):
        fitted, q = tracker.fit(hull, p)
    assert q["static_fraction"] > 0.1 and q["unexplained"] < 0.05, q
    scene = tracker.static(hull)
    assert not tracker.static(_hull_of(model, p)).any()  # no body voxel became scene
    assert scene.sum() >= 0.9 * len(_chair())
