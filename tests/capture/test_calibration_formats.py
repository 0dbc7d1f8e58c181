"""Calibration file formats: round trips, flavours, decomposition of real projection matrices, named errors."""

import numpy as np
import pytest

from capture.calib_formats import (
    decompose_projection_matrix,
    read_any_calibration,
    read_opencv_camera,
    write_calibration_as,
)
from capture.calibration import CalibrationError, load_calibration, toml_flavour
from capture.camera import Camera, rodrigues_to_matrix
from capture.tomlio import dumps, loads


def _studio(rng, *, distorted=True):
    return [
        Camera.look_at(
            f"cam{i}",
            [3 * np.cos(a), 3 * np.sin(a), rng.uniform(1.5, 3.0)],
            rng.normal(0, 0.2, 3) + [0, 0, 1],
            size=(644, 486),
            fov_deg=rng.uniform(50, 80),
            distortion=rng.normal(0, 0.05, 5) if distorted else np.zeros(5),
        )
        for i, a in enumerate(np.linspace(0, 2 * np.pi, 5)[:-1] + rng.uniform(0, 0.5))
    ]


def _assert_same_projection(a_cams, b_cams, rng):
    X = rng.uniform(-0.8, 0.8, (50, 3)) + [0, 0, 1]
    assert [c.name for c in b_cams] == [c.name for c in a_cams]
    for a, b in zip(a_cams, b_cams):
        assert b.size == a.size
        np.testing.assert_allclose(b.project(X), a.project(X), atol=1e-9, rtol=0)


@pytest.mark.parametrize("fmt", ["toml", "opencv-xml", "opencv-yaml", "easymocap"])
def test_round_trip_every_written_format(tmp_path, rng, fmt):
    cams = _studio(rng)
    target = tmp_path / ("calibration.toml" if fmt == "toml" else "calib")
    write_calibration_as(target, cams, fmt=fmt)
    back = read_any_calibration(target)
    _assert_same_projection(cams, back, rng)


def test_projection_matrix_round_trip(tmp_path, rng):
    cams = _studio(rng, distorted=False)
    write_calibration_as(tmp_path / "p", cams, fmt="projection")
    back = read_any_calibration(tmp_path / "p", size=(644, 486))
    X = rng.uniform(-0.8, 0.8, (50, 3)) + [0, 0, 1]
    for a, b in zip(cams, back):
        np.testing.assert_allclose(b.project(X), a.project(X), atol=1e-9)
    with pytest.raises(ValueError, match="distortion"):
        write_calibration_as(tmp_path / "q", _studio(rng), fmt="projection")


def test_decomposition_properties(rng):
    for _ in range(20):
        K = np.array([[rng.uniform(300, 2000), rng.normal(0, 2), rng.uniform(200, 600)],
                      [0, rng.uniform(300, 2000), rng.uniform(200, 500)], [0, 0, 1]])
        R = rodrigues_to_matrix(rng.normal(0, 1.5, 3))
        t = rng.normal(0, 3, 3)
        P = rng.choice([-1, 1]) * rng.uniform(0.01, 100) * K @ np.c_[R, t]
        K2, R2, t2 = decompose_projection_matrix(P)
        np.testing.assert_allclose(K2, K, rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(R2, R, atol=1e-9)
        np.testing.assert_allclose(t2, t, atol=1e-9)


def test_dancer_projection_matrices_reproject_exactly(shared_data, rng):
    folder = shared_data / "dancer_8view" / "calibration"
    cams = read_any_calibration(folder, size=(780, 582))
    assert len(cams) == 8
    X = rng.uniform([-1, -1, 0], [1, 1, 2], (200, 3))
    for path, cam in zip(sorted(folder.glob("cam*.xml")), cams):
        P = np.array(path.read_text().split("<camera>")[1].split("</camera>")[0].split(), dtype=float).reshape(3, 4)
        h = np.c_[X, np.ones(len(X))] @ P.T
        uv_P = h[:, :2] / h[:, 2:]
        np.testing.assert_allclose(cam.project(X), uv_P, atol=1e-6)
        assert cam.matrix[0, 0] > 0 and cam.matrix[1, 1] > 0
        assert np.linalg.det(cam.rotation) == pytest.approx(1.0, abs=1e-9)
        # the studio (origin, person's height) is in front of every camera; cameras above the floor
        assert cam.depth(np.array([0.0, 0.0, 0.9])) > 0
        assert 0.0 < cam.center[2] < 5.0


def test_uu_studio_config_xml_is_millimetres(shared_data):
    cam = read_opencv_camera(shared_data / "uu_studio" / "cam1" / "config.xml", size=(644, 486))
    assert cam.name == "cam1"
    assert cam.matrix[0, 0] == pytest.approx(490.756439, abs=1e-4)
    assert cam.distortion[0] == pytest.approx(-0.368704915, abs=1e-8)
    # the file's translation is 5.9 thousand mm long: read as metres
    assert np.linalg.norm(cam.translation) == pytest.approx(5.92, abs=0.01)
    cams = read_any_calibration(shared_data / "uu_studio", size=(644, 486))
    assert [c.name for c in cams] == ["cam1", "cam2", "cam3", "cam4"]


def _toml_camera(extra: str = "", t="[1200.0, -300.0, 2500.0]", dist="[0.01, -0.02, 0.0, 0.0]") -> str:
    return (
        '[cam_01]\nname = "cam01"\nsize = [ 1920.0, 1080.0]\n'
        "matrix = [ [ 1000.0, 0.0, 960.0], [ 0.0, 1000.0, 540.0], [ 0.0, 0.0, 1.0]]\n"
        f"distortions = {dist}\nrotation = [ 0.1, -0.2, 0.3]\ntranslation = {t}\n{extra}"
    )


def test_toml_flavours_and_units(tmp_path):
    cases = {
        # anipose: no unit, board in mm
        "anipose": (_toml_camera() + "\n[metadata]\nadjusted = true\nerror = 0.3\n", 1e-3),
        # Pose2Sim: metres, fisheye key
        "pose2sim": (_toml_camera("fisheye = false\n", t="[1.2, -0.3, 2.5]") + "\n[metadata]\nadjusted = false\nerror = 0.0\n", 1.0),
        # FreeMoCap: mm, charuco metadata
        "freemocap": (_toml_camera() + "\n[metadata]\ncharuco_square_size = 39.0\ncharuco_rows = 5\n", 1e-3),
        "contourcap": (_toml_camera(t="[1.2, -0.3, 2.5]") + '\n[metadata]\nunits = "m"\n', 1.0),
    }
    for flavour, (text, scale) in cases.items():
        assert toml_flavour(loads(text)) == flavour
        p = tmp_path / f"{flavour}.toml"
        p.write_text(text)
        (cam,) = load_calibration(p)
        expected = np.array([1200.0, -300.0, 2500.0]) * 1e-3
        np.testing.assert_allclose(cam.translation, expected, atol=1e-12)
        assert cam.size == (1920, 1080) and cam.name == "cam01"


def test_anipose_units_decided_once_per_file(tmp_path):
    """No unit stated: a camera 60 mm from the origin (a stereo partner of the origin camera) is read in
    the same unit as its 2.8 m-away neighbour, not as 60 m."""
    text = (_toml_camera(t="[0.0, 0.0, 0.0]").replace("cam_01", "cam_00").replace('"cam01"', '"cam00"')
            + _toml_camera(t="[-60.0, 0.0, 0.0]").replace("cam_01", "cam_02").replace('"cam01"', '"cam02"')
            + _toml_camera() + "\n[metadata]\nadjusted = true\n")
    p = tmp_path / "anipose.toml"
    p.write_text(text)
    cams = {c.name: c for c in load_calibration(p)}
    np.testing.assert_allclose(cams["cam02"].translation, [-0.060, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(cams["cam01"].translation, [1.2, -0.3, 2.5], atol=1e-12)


def test_malformed_files_name_file_section_key(tmp_path):
    p = tmp_path / "fish.toml"
    p.write_text(_toml_camera("fisheye = true\n"))
    with pytest.raises(CalibrationError, match=r"fish.toml \[cam_01\].*fisheye"):
        load_calibration(p)
    p = tmp_path / "units.toml"
    p.write_text(_toml_camera() + '\n[metadata]\nunits = "furlong"\n')
    with pytest.raises(CalibrationError, match=r"units.toml \[metadata\].*units"):
        load_calibration(p)
    x = tmp_path / "cam.xml"
    x.write_text('<?xml version="1.0"?>\n<opencv_storage>\n<CameraMatrix type_id="opencv-matrix"><rows>3</rows><cols>3</cols>'
                 "<dt>d</dt><data>1. 0. 1. 0. 1. 1. 0. 0. 1.</data></CameraMatrix>\n</opencv_storage>\n")
    with pytest.raises(CalibrationError, match=r"cam.xml \[root\].*DistortionCoeffs"):
        read_opencv_camera(x)
    y = tmp_path / "broken.xml"
    y.write_text("<opencv_storage><a>1</b>")
    with pytest.raises(CalibrationError, match="broken.xml"):
        read_any_calibration(y)
    q = tmp_path / "p.xml"
    q.write_text("<camera>1 2 3 4 5</camera>")
    with pytest.raises(CalibrationError, match=r"p.xml.*"):
        read_any_calibration(q)
    e = tmp_path / "emc"
    e.mkdir()
    (e / "intri.yml").write_text('%YAML:1.0\n---\nnames:\n  - "a"\nK_a: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n'
                                 "  data: [ 1., 0., 1., 0., 1., 1., 0., 0., 1. ]\n")
    (e / "extri.yml").write_text("%YAML:1.0\n---\nnames:\n  - \"a\"\n")
    with pytest.raises(CalibrationError, match=r"intri.yml \[camera a\].*dist_a"):
        read_any_calibration(e)
    with pytest.raises(CalibrationError, match="not found"):
        read_any_calibration(tmp_path / "missing.toml")


def test_folder_with_two_files_for_one_camera_is_refused(tmp_path, rng):
    cams = _studio(rng)[:2]
    write_calibration_as(tmp_path / "calib", cams, fmt="opencv-xml")
    assert [c.name for c in read_any_calibration(tmp_path / "calib")] == ["cam0", "cam1"]
    # cam0.xml and cam0.yml: one of them would silently win by sort order
    write_calibration_as(tmp_path / "calib", cams[:1], fmt="opencv-yaml")
    with pytest.raises(CalibrationError, match=r"calib: several files describe camera\(s\) \['cam0'\]"):
        read_any_calibration(tmp_path / "calib")


@pytest.mark.parametrize("old, new, key", [
    ("<image_width>644</image_width>", '<image_width>"wide"</image_width>', "image_width"),
    ("<units>m</units>", '<units>m</units>\n<Bad>"x"</Bad>', None),
])  # fmt: skip
def test_opencv_text_where_numbers_belong_is_named(tmp_path, rng, old, new, key):
    """FileStorage's real() of a text node is 1.8e308, not an error: such sizes/matrices must be refused."""
    path = write_calibration_as(tmp_path / "c", _studio(rng)[:1], fmt="opencv-xml")[0]
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))
    if key is None:  # an unrelated text key is fine
        assert read_opencv_camera(path).size == (644, 486)
        return
    with pytest.raises(CalibrationError, match=rf"cam0.xml \[root\]: key '{key}' must hold numbers"):
        read_opencv_camera(path)
    start, stop = text.index("<Translation"), text.index("</Translation>") + len("</Translation>")
    path.write_text(text[:start] + '<Translation>"a" "b" "c"</Translation>' + text[stop:])
    with pytest.raises(CalibrationError, match=r"key 'Translation' must hold numbers"):
        read_opencv_camera(path)


def test_written_toml_states_metres(tmp_path, rng):
    path = write_calibration_as(tmp_path / "c.toml", _studio(rng), fmt="toml")[0]
    assert loads(path.read_text())["metadata"]["units"] == "m"
    assert dumps(loads(path.read_text())) == path.read_text()
