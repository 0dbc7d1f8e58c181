"""Workers as threads on loopback zenoh, with stand-in segmenter and fitter (deterministic functions of the data)."""

from __future__ import annotations

import threading
import time

import numpy as np

from capture.calibration import save_calibration
from capture.camera import Camera
from capture.replay import ReplaySource
from capture.session import load_session, write_session_toml
from service.wire.bus import (
    Keys,
    ZenohSettings,
    free_port,
    open_session,
    wait_until_alive,
)
from service.wire.messages import ChamferMessage, FrameMessage
from service.workers.loops import run_camera_worker, run_segment_worker, run_track_worker

CAMS = ("cam0", "cam1", "cam2")


def wait_for(condition, timeout_s=10.0):
    """Poll ``condition()`` until true (True) or ``timeout_s`` (False)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def make_session(root, rng, n_frames=12, size=(40, 30)):
    import cv2

    cams = []
    for i, name in enumerate(CAMS):
        (root / name).mkdir(parents=True)
        for k in range(n_frames):
            img = rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8)
            cv2.imwrite(str(root / name / f"{k:06d}.png"), img)
        cams.append({"name": name, "images": f"{name}/%06d.png"})
    write_session_toml(root, name="t", fps=25.0, cameras=cams)
    save_calibration(root / "calibration.toml", [
        Camera.look_at(n, eye=(3 * np.cos(a), 3 * np.sin(a), 1.5), target=(0, 0, 1), size=size)
        for n, a in zip(CAMS, (0.0, 2.0, 4.0))])
    return load_session(root)


def segmenter(frame: FrameMessage, image) -> ChamferMessage:
    """A stand-in for the segmentation pipeline: the grey image, quantised, as one 'distance' array."""
    grey = image.mean(axis=2).astype(np.uint8)
    return ChamferMessage(frame.camera, frame.frame_id, frame.timestamp_ns, (image.shape[1], image.shape[0]),
                          (0, 0), 20.0, 1.0, (("edges", grey),))


def fitter(frame_id, timestamp_ns, chamfer):
    """A stand-in for the tracker: a deterministic function of every camera's chamfer image."""
    params = [float(chamfer[c].array("edges").astype(np.int64).sum()) if c in chamfer else -1.0 for c in CAMS]
    return {"frame": frame_id, "timestamp_ns": timestamp_ns, "ok": True, "model": "test", "params": params,
            "cameras": len(chamfer)}


class Studio:
    """Track worker (listening peer) + segment + camera workers as threads on loopback."""

    def __init__(self, keys: Keys):
        self.port, self.keys, self.stop = free_port(), keys, threading.Event()
        self.sessions, self.threads, self.results = [], [], {}

    def session(self, listen=False):
        s = open_session(ZenohSettings.loopback(self.port, listen=listen))
        self.sessions.append(s)
        return s

    def start(self, name, fn, *args, **kw):
        def target():
            self.results[name] = fn(*args, **kw)
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        self.threads.append(t)

    def run_live(self, session, fit, segment, cameras=CAMS, **track_kw) -> tuple[list, dict]:
        """Live track + segment workers for CAMS, then ``cameras`` replayed in real time by a camera
        worker (until their end): (the poses so far, the camera worker's counters)."""
        poses = []
        self.start("track", run_track_worker, self.session(listen=True), self.keys, CAMS, fit, mode="live",
                   set_timeout_s=0.3, stop=self.stop, on_pose=poses.append, **track_kw)
        self.start("segment", run_segment_worker, self.session(), self.keys, {c: segment for c in CAMS},
                   mode="live", stop=self.stop)
        cam_session = self.session()
        assert wait_until_alive(cam_session, self.keys, ("track", "segment"), timeout_s=10.0)
        sources = {c: ReplaySource(session, c, pacing="realtime") for c in cameras}
        for s in sources.values():
            s.open()
        return poses, run_camera_worker(cam_session, self.keys, sources, mode="live", stop=self.stop)

    def close(self):
        self.stop.set()
        for t in self.threads:
            t.join(5.0)
        for s in reversed(self.sessions):
            s.close()

