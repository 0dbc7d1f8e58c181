"""A background model file of random bytes is a ``SegmentationError`` naming it (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest

from segmentation.background import BackgroundModel
from segmentation.errors import SegmentationError


@pytest.mark.parametrize("body", [b"", b"PK\x03\x04" + bytes(100), np.random.default_rng(3).bytes(2000)])
def test_random_bytes_background_file(tmp_path, body):
    path = tmp_path / "background.npz"
    path.write_bytes(body)
    with pytest.raises(SegmentationError, match="not a background model file") as exc:
        BackgroundModel.load(path)
    assert str(path) in str(exc.value) and isinstance(exc.value, ValueError)
