"""Tiny synthetic session directories for the capture tests (written into tmp_path).

``make_session`` writes FFV1 videos (lossless here) or PNG sequences of seeded
random images, optional timestamp CSVs with dropped frames, and a look-at
calibration.  Imported by the other capture test modules.
"""

from __future__ import annotations

import cv2
import numpy as np

from tests.support.sessions import SIZE, make_images, make_session, write_video  # noqa: F401


def test_factory_writes_a_loadable_lossless_session(tmp_path, rng):
    session, expected = make_session(tmp_path / "s", rng, n_frames=3)
    assert session.camera_names == ("cam0", "cam1")
    cap = cv2.VideoCapture(str(session.camera("cam1").video))
    ok, first = cap.read()
    cap.release()
    assert ok and np.array_equal(first, expected["cam1"][0])
