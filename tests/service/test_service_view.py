"""`contourcap view --save`: a real zenoh peer publishes poses, frames, chamfer images and hulls; the .rrd
written by the bridge is read back and holds the frusta, skeleton, images, silhouettes, hull and metrics."""

from __future__ import annotations

import argparse
import collections
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from capture.calibration import save_calibration
from capture.camera import Camera
from service.wire.bus import Keys, ZenohSettings, declare_publisher, free_port, open_session
from service.wire.hull import HullMessage
from service.wire.messages import ChamferMessage, FrameMessage
from service.wire.records import PoseRecord

rrchunk = pytest.importorskip("rerun.chunk")


def _publish(port, stop, rng):
    s = open_session(ZenohSettings.loopback(port, listen=True))
    keys = Keys("view1")
    pubs = {k: declare_publisher(s, k) for k in (keys.pose, keys.frame("cam0"), keys.frame("cam1"),
                                                  keys.chamfer("cam0"), keys.hull)}
    hull = HullMessage(0, 0, rng.uniform(-0.3, 0.3, (20, 3)), np.full(20, 0.03), rng.uniform(0, 255, (20, 3)), 0.03)
    img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    sil = np.full((20, 30), 40, np.uint8)
    sil[5:15, 10:20] = 0
    k = 0
    while not stop.is_set():
        pubs[keys.frame("cam0")].put(FrameMessage.from_image("cam0", k, k * 1000, img, encoding="jpeg").to_bytes())
        pubs[keys.frame("cam1")].put(FrameMessage.from_image("cam1", k, k * 1000, img).to_bytes())
        pubs[keys.chamfer("cam0")].put(ChamferMessage("cam0", k, k * 1000, (64, 48), (10, 10), 10.0, 4.0,
                                                      (("silhouette", sil), ("edges", sil))).to_bytes())
        joints = {"pelvis": [0, 0, 0.9], "neck": [0, 0, 1.5], "head": [0, 0, 1.7], "spine": [0, 0, 1.2],
                  "left_hand_tip": [0.5, 0, 1.4]}
        pubs[keys.pose].put(PoseRecord.from_dict({"frame": k, "timestamp_ns": k * 1000, "ok": True, "joints": joints,
                                                  "rms_px": 1.0, "latency_ms": 5.0, "cameras": 2}).to_bytes())
        pubs[keys.hull].put(replace(hull, frame_id=k, timestamp_ns=k * 1000).to_bytes())
        k += 1
        time.sleep(0.02)
    s.close()


def test_view_saves_rrd(tmp_path, rng):
    from service.commands import view

    cams = [Camera.look_at(f"cam{i}", eye=(3, 2 * i - 1, 2), target=(0, 0, 1), size=(64, 48)) for i in range(2)]
    save_calibration(tmp_path / "calibration.toml", cams)
    port, stop = free_port(), threading.Event()
    t = threading.Thread(target=_publish, args=(port, stop, rng), daemon=True)
    t.start()
    rrd = tmp_path / "out.rrd"
    parser = argparse.ArgumentParser()
    view.add_args(parser)
    args = parser.parse_args(["--connect", f"tcp/127.0.0.1:{port}", "--studio", "view1", "--save", str(rrd),
                              "--calibration", str(tmp_path / "calibration.toml"), "--count", "8",
                              "--image-every", "1", "--duration-s", "10"])
    try:
        assert view.run(args) == 0
    finally:
        stop.set()
        t.join(5)
    rows = collections.Counter()
    for chunk in rrchunk.RrdReader(rrd).stream():
        rows[str(chunk.entity_path)] += chunk.num_rows
    assert rows["/world/skeleton"] >= 8 + 1  # 8 poses + the static annotation context
    assert rows["/world/cameras/cam0"] >= 2 and rows["/world/cameras/cam1"] >= 2  # transform + pinhole
    assert rows["/world/cameras/cam0/image"] >= 1 and rows["/world/cameras/cam1/image"] >= 1
    assert rows["/world/cameras/cam0/silhouette"] >= 1
    assert rows["/world/hull"] >= 1
    assert rows["/metrics/rms_px"] >= 8 and rows["/metrics/latency_ms"] >= 8
