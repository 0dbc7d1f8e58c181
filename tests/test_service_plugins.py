"""Stand-ins for segmentation and tracker that worker *processes* load with ``--plugin`` in the service
tests (``tests.test_service_plugins:segmenter_factory`` / ``:fitter_factory``), plus their own test.

They are deliberately simple, deterministic functions of the data that crossed the bus, so that the
tests can compare what the pipeline published with what the data says."""

from __future__ import annotations

import numpy as np

from service.messages import ChamferMessage, FrameMessage


def segmenter(frame: FrameMessage, image) -> ChamferMessage:
    """The grey image, quantised, as one 'edges' array."""
    grey = image.mean(axis=2).astype(np.uint8)
    return ChamferMessage(frame.camera, frame.frame_id, frame.timestamp_ns, (image.shape[1], image.shape[0]),
                          (0, 0), 20.0, 1.0, (("edges", grey),))


def segmenter_factory(camera: str):
    return segmenter


def fitter(frame_id, timestamp_ns, chamfer):
    """params[i] = sum of camera i's array (cameras sorted by name), -1 if absent."""
    names = sorted(chamfer)
    return {"frame": frame_id, "timestamp_ns": timestamp_ns, "ok": True, "model": "test",
            "params": [float(chamfer[c].array("edges").astype(np.int64).sum()) for c in names],
            "joints": {"head": [0.0, 0.0, float(len(names))]}, "cameras": len(chamfer)}


def fitter_factory(cfg):
    return fitter


def test_plugins_are_functions_of_the_data(rng):
    img = rng.integers(0, 256, (6, 8, 3), dtype=np.uint8)
    msg = segmenter(FrameMessage.from_image("cam0", 1, 2, img), img)
    rec = fitter(1, 2, {"cam0": msg})
    assert rec["params"] == [float(img.mean(axis=2).astype(np.uint8).astype(np.int64).sum())]
    assert rec["cameras"] == 1
