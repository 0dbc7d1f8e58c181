"""The reverse term's boundary samples and rays, remembered per (chamfer object, camera)."""

from __future__ import annotations

import gc

import numpy as np

from segmentation.distance import chamfer_images
from tracker.fitting import boundary
from tracker.fitting.boundary import boundary_rays, boundary_samples
from tracker.synthetic.scene import ring_cameras


def _chamfer(rng, offset=0):
    mask = np.zeros((120, 160), np.uint8)
    x0, y0 = rng.integers(10, 60), rng.integers(10, 40)
    mask[y0:y0 + 50 + offset, x0:x0 + 30] = 255
    return chamfer_images(mask, np.zeros_like(mask))


def test_remembered_samples_and_rays_are_the_computed_ones(rng):
    cams = ring_cameras(2, size=(160, 120))
    ch = _chamfer(rng)
    s1, d1 = boundary_rays(ch, cams[0], max_points=40)
    np.testing.assert_array_equal(s1, boundary_samples(ch, max_points=40))
    np.testing.assert_array_equal(d1, cams[0].rays(s1))
    assert len(s1) == 40 and len(np.unique(s1, axis=0)) == 40
    s2, d2 = boundary_rays(ch, cams[0], max_points=40)
    assert s2 is s1 and d2 is d1 and not s1.flags.writeable  # remembered, and nobody can change them
    # another camera, another sample count, another chamfer object: computed for it
    _, d3 = boundary_rays(ch, cams[1], max_points=40)
    np.testing.assert_array_equal(d3, cams[1].rays(s1))
    assert len(boundary_rays(ch, cams[0], max_points=10)[0]) == 10
    other = _chamfer(rng, offset=7)
    np.testing.assert_array_equal(boundary_rays(other, cams[0], max_points=40)[0],
                                  boundary_samples(other, max_points=40))
    # without rays: zeros, and a later call with rays computes them
    fresh = _chamfer(rng, offset=3)
    s4, d4 = boundary_rays(fresh, cams[0], max_points=40, rays=False)
    assert not d4.any() and d4.shape == (len(s4), 3)
    _, d5 = boundary_rays(fresh, cams[0], max_points=40)
    np.testing.assert_array_equal(d5, cams[0].rays(s4))


def test_memo_keeps_nothing_alive_and_stays_bounded(rng):
    cams = ring_cameras(1, size=(160, 120))
    for _ in range(boundary.MEMO_SIZE + 10):
        boundary_rays(_chamfer(rng), cams[0], max_points=20)
    assert len(boundary._memo) <= boundary.MEMO_SIZE
    gc.collect()
    assert all(entry[0]() is None for entry in boundary._memo.values())  # the chamfer objects are gone
    # an id reused by a new object is not mistaken for the dead one's
    ch = _chamfer(rng, offset=11)
    np.testing.assert_array_equal(boundary_rays(ch, cams[0], max_points=20)[0], boundary_samples(ch, max_points=20))
