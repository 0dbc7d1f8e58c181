"""Capture: camera model, calibration I/O, sessions, camera sources, trigger box, frame-set sync, recorder."""
from capture.camera import Camera

__all__ = ["Camera"]
