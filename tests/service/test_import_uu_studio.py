"""`contourcap import uu_studio` on the real recording: a loadable session with a working calibration and readable media."""

import cv2
import numpy as np
import pytest

from capture.camera import Camera, rodrigues_to_matrix
from capture.session import load_session
from capture.uu_studio import UUImportError, import_uu_studio
from service.cli import main


def _person_mask(video, background) -> np.ndarray:
    """Largest changed region of the first frame against the first background frame, (h, w) bool."""
    frame = cv2.VideoCapture(str(video)).read()[1]
    bg = cv2.VideoCapture(str(background)).read()[1]
    m = (np.abs(frame.astype(int) - bg.astype(int)).max(axis=2) > 40).astype(np.uint8)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    _, labels, stats, _ = cv2.connectedComponentsWithStats(m)
    return labels == 1 + np.argmax(stats[1:, cv2.CC_STAT_AREA])


def _hull_coverage(cams, masks, voxels) -> np.ndarray:
    """Per camera: fraction of its silhouette covered by the projected visual hull of all cameras, (n_cams,)."""
    inside = []
    for cam, m in zip(cams, masks):
        uv = cam.project(voxels)
        ok = (cam.depth(voxels) > 0) & cam.in_image(uv)
        uv = np.where(ok[:, None], uv, 0.0).round().astype(int)
        inside.append(ok & m[uv[:, 1], uv[:, 0]])
    hull = voxels[np.all(inside, axis=0)]
    out = []
    for cam, m in zip(cams, masks):
        uv = cam.project(hull)
        uv = uv[cam.in_image(uv)].round().astype(int)
        proj = np.zeros(m.shape, np.uint8)
        proj[uv[:, 1], uv[:, 0]] = 1
        proj = cv2.dilate(proj, np.ones((3, 3), np.uint8)).astype(bool)
        out.append((proj & m).sum() / m.sum())
    return np.array(out)


def _yawed(cam: Camera, deg: float) -> Camera:
    """The camera turned by ``deg`` about its own vertical image axis, centre fixed."""
    Ry = rodrigues_to_matrix([0.0, np.radians(deg), 0.0])
    return Camera(cam.name, cam.matrix, cam.distortion, Ry @ cam.rotation, Ry @ cam.translation, cam.size)


@pytest.fixture(scope="module")
def imported(shared_data, tmp_path_factory):
    """The uu_studio recording imported once through the CLI: (session dir, printed output, exit status)."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("import") / "uu"
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        rc = main(["import", "uu_studio", str(shared_data / "uu_studio"), str(out), "--quiet"])
    return out, buf.getvalue(), rc


def test_import_uu_studio_gives_a_loadable_session(imported, shared_data, capsys):
    out, printed, rc = imported
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
    # OUT a file, or an empty name: refused before the (slow) calibration, nothing written
    (out.parent / "a_file").write_text("x")
    assert main(["import", "uu_studio", str(shared_data / "uu_studio"), str(out.parent / "a_file"), "--quiet"]) == 2
    assert "a_file: exists and is not a folder" in capsys.readouterr().err
    assert main(["import", "uu_studio", str(shared_data / "uu_studio"), str(out.parent / "o2"), "--quiet",
                 "--name", ""]) == 2
    assert "session name must be a non-empty string" in capsys.readouterr().err
    assert not (out.parent / "o2").exists()


def test_imported_calibration_agrees_with_the_person_silhouettes(imported):
    """Independent of the board: the visual hull carved by all four silhouettes explains most of each
    silhouette, and turning a manually calibrated camera by 1 degree about its centre explains less."""
    sess = load_session(imported[0])
    masks = [_person_mask(c.video, c.background) for c in sess.cameras]
    axes = [np.arange(-1.5, 2.0, 0.04), np.arange(-1.5, 2.5, 0.04), np.arange(0.0, 2.0, 0.04)]
    voxels = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    cams = list(sess.calibration)
    base = _hull_coverage(cams, masks, voxels)
    assert base.min() > 0.6 and base.mean() > 0.75, base  # measured (4 cm voxels): 0.89, 0.70, 0.70, 0.89
    for k in (0, 3):  # cam1 and cam4 used manual outlines
        for deg in (-1.0, 1.0):
            turned = cams[:k] + [_yawed(cams[k], deg)] + cams[k + 1:]
            assert _hull_coverage(turned, masks, voxels).mean() < base.mean(), (cams[k].name, deg)


def test_import_names_missing_source_file(tmp_path):
    (tmp_path / "src" / "cam1").mkdir(parents=True)
    (tmp_path / "src" / "checkerboard.xml").write_text("<opencv_storage></opencv_storage>")
    with pytest.raises(UUImportError, match=r"cam1/config.xml: missing"):
        import_uu_studio(tmp_path / "src", tmp_path / "out")
    assert not (tmp_path / "out").exists()  # nothing written
