"""`contourcap import uu_studio` on the real recording: a loadable session with a working calibration and readable media."""

import cv2
import numpy as np
import pytest

from capture.session import load_session
from capture.uu_studio import UUImportError, import_uu_studio
from service.cli import main


def test_import_uu_studio_gives_a_loadable_session(shared_data, tmp_path, capsys):
    out = tmp_path / "uu"
    rc = main(["import", "uu_studio", str(shared_data / "uu_studio"), str(out), "--quiet"])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "wrote session" in printed and "4 cameras, 50 fps" in printed
    sess = load_session(out)
    assert sess.camera_names == ("cam1", "cam2", "cam3", "cam4")
    assert sess.fps == 50.0
    board_centre = np.array([0.4025, 0.2875, 0.0])
    for cam, model in zip(sess.cameras, sess.calibration):
        assert model.name == cam.name and model.size == (644, 486)
        assert 1.0 < model.center[2] < 4.0
        assert model.in_image(model.project(board_centre))
        for path in (cam.video, cam.background):
            cap = cv2.VideoCapture(str(path))
            frames = []
            for _ in range(3):
                ok, frame = cap.read()
                assert ok, path
                frames.append(frame)
            cap.release()
            assert frames[0].shape == (486, 644, 3)
        assert cam.video.resolve() == (shared_data / "uu_studio" / cam.name / "video.avi").resolve()
    # the take's frames are distinct images of the room, not blank
    cap = cv2.VideoCapture(str(sess.cameras[0].video))
    ok, first = cap.read()
    assert ok and first.std() > 20
    # a second import into the same folder is refused without --force
    assert main(["import", "uu_studio", str(shared_data / "uu_studio"), str(out), "--quiet"]) == 2
    assert "already holds a session" in capsys.readouterr().err


def test_import_names_missing_source_file(tmp_path):
    (tmp_path / "src" / "cam1").mkdir(parents=True)
    (tmp_path / "src" / "checkerboard.xml").write_text("<opencv_storage></opencv_storage>")
    with pytest.raises(UUImportError, match=r"cam1/config.xml: missing"):
        import_uu_studio(tmp_path / "src", tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written
