"""The compiled exact distance transform: correctly rounded exact distances (scipy's EDT in float32), and
OpenCV's precise values within one float32 step (its square root is not correctly rounded), so the
quantised chamfer images are OpenCV's bit for bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.ndimage import distance_transform_edt

from segmentation import distance_to_mask
from segmentation.edt import MAX_TABLE_PX, exact_codes, exact_distance
from segmentation.quantise import quantise


def _opencv_precise(mask: np.ndarray, max_px: float) -> np.ndarray:
    if not mask.any():
        return np.full(mask.shape, max_px, np.float32)
    dt = cv2.distanceTransform(cv2.compare(mask, 0, cv2.CMP_EQ), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    return cv2.min(dt, float(max_px))


def _exact(mask: np.ndarray, max_px: float) -> np.ndarray:
    if not mask.any():
        return np.full(mask.shape, max_px, np.float32)
    return np.minimum(distance_transform_edt(mask == 0).astype(np.float32), np.float32(max_px))


def _quantised(d: np.ndarray) -> np.ndarray:
    return cv2.convertScaleAbs(d, alpha=4.0)  # chamfer_images' uint8 path at 0.25 px


@pytest.mark.parametrize("max_px", [48.0, 7.3, 1.0, 500.0])
def test_exact_and_as_opencv_precise(rng, max_px):
    for _ in range(60):
        h, w = (int(v) for v in rng.integers(1, 90, 2))
        density = rng.choice([0.0, 0.0005, 0.01, 0.2, 0.9])
        mask = ((rng.random((h, w)) < density) * 255).astype(np.uint8)
        got = exact_distance(mask, max_px)
        assert got.dtype == np.float32 and got.shape == (h, w)
        np.testing.assert_array_equal(got, _exact(mask, max_px))
        ref = _opencv_precise(mask, max_px)
        assert np.abs(got - ref).max() <= 4e-6 * max(max_px, 1.0)
        if max_px <= 48.0:
            np.testing.assert_array_equal(_quantised(got), _quantised(ref))


def test_person_sized_silhouette_equals_scipy_and_opencv():
    m = np.zeros((457, 170), np.uint8)
    cv2.ellipse(m, (85, 228), (40, 180), 5, 0, 360, 255, -1)
    cv2.rectangle(m, (10, 30), (25, 60), 255, -1)  # a second blob: envelopes with several sites
    got = distance_to_mask(m, max_distance_px=48.0)
    np.testing.assert_array_equal(got, _exact(m, 48.0))
    np.testing.assert_array_equal(_quantised(got), _quantised(_opencv_precise(m, 48.0)))
    assert (got[m > 0] == 0).all()


def test_non_contiguous_and_bool_masks(rng):
    mask = (rng.random((60, 80)) < 0.02)
    view = mask[::2, 5:70]
    got = distance_to_mask(view, max_distance_px=20.0)
    np.testing.assert_array_equal(got, _exact(view, 20.0))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_bad_truncation_rejected(bad):
    with pytest.raises(ValueError, match="max_distance_px"):
        distance_to_mask(np.zeros((4, 4), np.uint8), max_distance_px=bad)


@pytest.mark.parametrize("max_px, resolution, dtype", [(48.0, 0.25, np.uint8), (7.3, 0.1, np.uint8),
                                                       (48.0, 0.125, np.uint16), (300.0, 0.25, np.uint16)])
def test_codes_are_the_quantised_exact_distance(rng, max_px, resolution, dtype):
    for _ in range(40):
        h, w = (int(v) for v in rng.integers(1, 120, 2))
        density = rng.choice([0.0, 0.0005, 0.01, 0.2, 0.9])
        mask = ((rng.random((h, w)) < density) * 255).astype(np.uint8)
        got = exact_codes(mask, max_px, resolution, dtype)
        assert got.dtype == dtype and got.shape == (h, w)
        np.testing.assert_array_equal(got, quantise(_exact(mask, max_px), resolution_px=resolution, dtype=dtype))


def test_truncation_beyond_the_table_is_opencv_precise():
    mask = np.zeros((40, 2100), np.uint8)
    mask[0, 0] = mask[39, 10] = 255  # the far end: distances beyond MAX_TABLE_PX and truncated
    max_px = MAX_TABLE_PX + 1000.5
    np.testing.assert_array_equal(exact_distance(mask, max_px), _opencv_precise(mask, max_px))
    np.testing.assert_array_equal(exact_codes(mask, max_px, 0.25, np.uint16),
                                  quantise(_opencv_precise(mask, max_px), resolution_px=0.25, dtype=np.uint16))
    assert exact_distance(mask, max_px).max() > MAX_TABLE_PX
