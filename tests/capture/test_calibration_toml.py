import numpy as np
import pytest

from capture.calibration import CalibrationError, load_calibration, save_calibration
from capture.camera import Camera


def test_anipose_round_trip_is_exact(tmp_path, rng):
    cams = [
        Camera.look_at(f"cam{i}", [3 * np.cos(a), 3 * np.sin(a), 1.8], [0, 0, 1], distortion=rng.normal(0, 0.05, 5))
        for i, a in enumerate(np.linspace(0, 2 * np.pi, 5)[:-1])
    ]
    path = save_calibration(tmp_path / "calibration.toml", cams)
    back = load_calibration(path)
    X = rng.uniform(-0.5, 0.5, (20, 3)) + [0, 0, 1]
    assert [c.name for c in back] == [c.name for c in cams]
    for a, b in zip(cams, back):
        np.testing.assert_allclose(a.project(X), b.project(X), atol=1e-9)


def test_missing_key_named(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text('[cam_00]\nname = "c"\nsize = [10, 10]\nmatrix = [[1,0,0],[0,1,0],[0,0,1]]\ndistortions = [0,0,0,0]\nrotation = [0,0,0]\n')
    with pytest.raises(CalibrationError, match=r"bad.toml \[cam_00\].*translation"):
        load_calibration(p)


_CAM = ('[cam_00]\nname = "{name}"\nsize = [10, 10]\nmatrix = [[1,0,5],[0,1,5],[0,0,1]]\n'
        'distortions = [0,0,0,0]\nrotation = {rotation}\ntranslation = [0,0,1]\n')


@pytest.mark.parametrize("text, match", [
    (_CAM.format(name="c", rotation='["a", 0, 0]'), r"bad.toml \[cam_00\]: key 'rotation' is not numeric"),
    (_CAM.format(name="c", rotation="[0, 0]"), r"bad.toml \[cam_00\]: key 'rotation' must be"),
    ("metadata = 5\n" + _CAM.format(name="c", rotation="[0, 0, 0]"), r"bad.toml: key 'metadata' must be a table"),
    (_CAM.format(name="c", rotation="[0, 0, 0]") + _CAM.replace("cam_00", "cam_01").format(name="c", rotation="[0, 0, 0]"),
     r"bad.toml: camera names must be unique, repeated: \['c'\]"),
])  # fmt: skip
def test_malformed_calibration_is_named(tmp_path, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(CalibrationError, match=match):
        load_calibration(p)


def test_unreadable_calibration_file_is_named(tmp_path):
    (tmp_path / "binary.toml").write_bytes(b"\x00\xff\xfe garbage \xc3\x28")
    with pytest.raises(CalibrationError, match=r"binary.toml: invalid TOML: not UTF-8"):
        load_calibration(tmp_path / "binary.toml")
    (tmp_path / "folder.toml").mkdir()
    with pytest.raises(CalibrationError, match=r"folder.toml: cannot read"):
        load_calibration(tmp_path / "folder.toml")


def test_load_file_maps_every_failure_to_the_callers_error(tmp_path):
    from capture.tomlio import load_file

    bad = tmp_path / "bad.toml"
    bad.write_text("[cam\n")
    for path, match in ((tmp_path / "absent.toml", "absent.toml: thing not found"), (bad, "bad.toml: invalid TOML"),
                        (tmp_path, "cannot read")):
        with pytest.raises(CalibrationError, match=match):
            load_file(path, error=CalibrationError, what="thing")
    with pytest.raises(FileNotFoundError):
        load_file(tmp_path / "absent.toml")
