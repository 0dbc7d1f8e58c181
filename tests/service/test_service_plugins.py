"""Stand-ins for segmentation and tracker that worker *processes* load with ``--plugin`` in the service
tests (``tests.support.plugins:segmenter_factory`` / ``:fitter_factory``), plus their own test.

They are deliberately simple, deterministic functions of the data that crossed the bus, so that the
tests can compare what the pipeline published with what the data says."""

from __future__ import annotations

import numpy as np

from service.wire.messages import FrameMessage
from tests.support.plugins import fitter, segmenter


def test_plugins_are_functions_of_the_data(rng):
    img = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    msg = segmenter(FrameMessage.from_image("cam0", 1, 2, img), img)
    rec = fitter(1, 2, {"cam0": msg})
    assert rec["params"] == [float(img.mean(axis=2).astype(np.uint8).astype(np.int64).sum())]
    assert rec["cameras"] == 1
