"""Capture: camera model, calibration I/O, sessions, camera sources, trigger box, frame-set sync, recorder.

Everything between the cameras and the rest of the pipeline; no zenoh here (the service wires these
into workers).
"""

from capture.calib_formats import read_any_calibration, write_calibration_as
from capture.calibration import CalibrationError, load_calibration, save_calibration
from capture.camera import Camera
from capture.opencv_source import OpenCVSource
from capture.recorder import DiskFullError, Recorder, RecorderError
from capture.replay import ReplaySource, iter_frame_sets, read_frames
from capture.session import Session, SessionCamera, SessionError, load_session, write_session_toml
from capture.sources import EndOfStream, Frame, OpenError, Source, SourceError, StreamLostError
from capture.sync import FrameSet, FrameSetAssembler, FrameSynchronizer
from capture.trigger import SoftwareTrigger, TriggerBox

__all__ = [
    "Camera", "CalibrationError", "load_calibration", "save_calibration", "read_any_calibration",
    "write_calibration_as", "Session", "SessionCamera", "SessionError", "load_session", "write_session_toml",
    "Frame", "Source", "SourceError", "OpenError", "StreamLostError", "EndOfStream", "ReplaySource",
    "read_frames", "iter_frame_sets", "OpenCVSource", "FrameSet", "FrameSetAssembler", "FrameSynchronizer", "TriggerBox",
    "SoftwareTrigger", "Recorder", "RecorderError", "DiskFullError",
]  # fmt: skip
