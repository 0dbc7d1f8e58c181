"""Fuzzing the session and calibration readers (issue 16): any bytes, and TOML with the right keys
holding values of every type, give a ``CaptureError`` (SessionError, CalibrationError) or a value,
never another exception.  ``pytest --fuzz-long`` runs 100x more examples."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from capture.calibration import load_calibration, save_calibration
from capture.camera import Camera
from capture.errors import CaptureError
from capture.session import load_session
from capture.tomlio import dumps
from tests.support.fuzz import hostile_bytes, toml_tables, toml_values
from tests.support.sessions import make_session

SLOW = settings(suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
CAMERA_KEYS = ("name", "size", "matrix", "distortions", "rotation", "translation", "fisheye")


def _calibration_seed(tmp_path) -> bytes:
    cams = [Camera.look_at(f"cam{i}", (3 * np.cos(i), 3 * np.sin(i), 1.5), (0, 0, 1), size=(64, 48)) for i in range(2)]
    save_calibration(tmp_path / "seed.toml", cams)
    return (tmp_path / "seed.toml").read_bytes()


@SLOW
@given(data=st.data())
def test_calibration_reader_bytes(tmp_path_factory, data):
    d = tmp_path_factory.mktemp("calib")
    path = d / "calibration.toml"
    path.write_bytes(data.draw(hostile_bytes(_calibration_seed(d))))
    try:
        cams = load_calibration(path)
    except CaptureError:
        return
    assert all(isinstance(c, Camera) for c in cams)


@SLOW
@given(tables=st.lists(toml_tables(CAMERA_KEYS), min_size=1, max_size=3), meta=toml_values)
def test_calibration_reader_wrong_types(tmp_path_factory, tables, meta):
    path = tmp_path_factory.mktemp("calib") / "calibration.toml"
    data = {f"cam_{i:02d}": t for i, t in enumerate(tables)}
    data["metadata"] = {"units": meta}
    try:
        path.write_text(dumps(data))
    except (TypeError, ValueError):
        return
    try:
        load_calibration(path)
    except CaptureError:
        pass


@SLOW
@given(data=st.data())
def test_session_reader_bytes(tmp_path_factory, data):
    d = tmp_path_factory.mktemp("session")
    make_session(d, np.random.default_rng(0), cams=("cam0", "cam1"), n_frames=2, csv=True)
    seed = (d / "session.toml").read_bytes()
    (d / "session.toml").write_bytes(data.draw(hostile_bytes(seed)))
    if data.draw(st.booleans()):
        (d / "cam0.csv").write_bytes(data.draw(hostile_bytes((d / "cam0.csv").read_bytes())))
    try:
        load_session(d)
    except CaptureError:
        pass


@SLOW
@given(session=toml_tables(("name", "fps")), subject=toml_tables(("height_m", "segment_lengths")),
       cameras=st.lists(toml_tables(("name", "video", "images", "background", "timestamps")), max_size=3))
def test_session_reader_wrong_types(tmp_path_factory, session, subject, cameras):
    d = tmp_path_factory.mktemp("session")
    try:
        (d / "session.toml").write_text(dumps({"session": session, "subject": subject, "camera": cameras}))
    except (TypeError, ValueError):
        return
    try:
        load_session(d, require_calibration=False)
    except CaptureError:
        pass
