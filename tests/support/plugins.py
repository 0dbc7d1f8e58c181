"""Stand-ins for segmentation and tracker that worker *processes* load with ``--plugin`` in the service tests
(``tests.support.plugins:segmenter_factory`` / ``:fitter_factory``).

They are deliberately simple, deterministic functions of the data that crossed the bus, so that the tests can
compare what the pipeline published with what the data says."""

from __future__ import annotations

import numpy as np

from service.wire.messages import ChamferMessage, FrameMessage


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



def frame_ids_fitter(frame_id, timestamp_ns, chamfer):
    """:func:`fitter`, plus ``camera_frames`` {camera: frame id of its chamfer}: what a mixed set would show."""
    return {**fitter(frame_id, timestamp_ns, chamfer),
            "camera_frames": {c: int(m.frame_id) for c, m in chamfer.items()}}


def frame_ids_fitter_factory(cfg):
    return frame_ids_fitter
