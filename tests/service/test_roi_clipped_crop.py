"""``roi_clipped_crop`` (the live segmenter's test on the box's silhouette) agrees with ``roi_clipped``."""

from __future__ import annotations

import numpy as np
import pytest

from service.workers.components import roi_clipped, roi_clipped_crop


def test_crop_test_equals_full_image_test(rng):
    w, h = 60, 40
    for _ in range(300):
        x0, x1 = sorted(int(v) for v in rng.choice(w + 1, 2, replace=False))
        y0, y1 = sorted(int(v) for v in rng.choice(h + 1, 2, replace=False))
        sil = np.zeros((h, w), np.uint8)
        bx, by = int(rng.integers(0, w)), int(rng.integers(0, h))
        sil[by:by + int(rng.integers(1, 20)), bx:bx + int(rng.integers(1, 20))] = 255
        full = np.zeros_like(sil)
        full[y0:y1, x0:x1] = sil[y0:y1, x0:x1]  # segment_frame's silhouette: zero outside the box
        assert roi_clipped_crop(sil[y0:y1, x0:x1], (x0, y0, x1, y1), (w, h)) == roi_clipped(full, (x0, y0, x1, y1), (w, h))


def test_crop_of_wrong_shape_rejected():
    with pytest.raises(ValueError, match="silhouette_roi"):
        roi_clipped_crop(np.zeros((5, 5), np.uint8), (0, 0, 6, 5), (10, 10))
