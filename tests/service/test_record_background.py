"""`contourcap record --background 2s` stores an empty-room plate with the session, and `track` warns
once when it must fall back to a temporal median (issue 16)."""

from __future__ import annotations

import numpy as np

from capture.replay import read_frames
from capture.session import load_session
from service.backgrounds import learn_background
from service.cli import main
from service.commands.track import median_warning
from tests.support.sessions import make_session


def _config(path, session_dir, cams=("cam0", "cam1")):
    lines = ['[studio]', 'name = "lab"', f'session = "{session_dir}"', ""]
    for c in cams:
        lines += ["[[camera]]", f'name = "{c}"', 'host = "h1"', 'backend = "replay"', ""]
    path.write_text("\n".join(lines))
    return path


def test_record_background_stores_the_plate_the_tracker_learns_from(tmp_path, rng, capsys):
    src, _ = make_session(tmp_path / "src", rng, n_frames=5, background=True)
    cfg = _config(tmp_path / "studio.toml", src.root)
    rc = main(["record", "--config", str(cfg), str(tmp_path / "out"), "--codec", "ffv1", "--pacing", "fast",
               "--background", "2s"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert "background: stored" in err
    rec = load_session(tmp_path / "out", require_calibration=False)
    for name in ("cam0", "cam1"):
        assert rec.camera(name).background == rec.root / "background" / f"{name}.avi"
        a = [f.image for f in read_frames(src, name, background=True)]
        b = [f.image for f in read_frames(rec, name, background=True)]
        assert len(a) == len(b) == 3 and all(np.array_equal(x, y) for x, y in zip(a, b))  # lossless
        learnt, imported = learn_background(rec, name), learn_background(src, name)
        assert learnt.source == imported.source == "video"
        assert np.array_equal(learnt.model.mean_yuv, imported.model.mean_yuv)  # the same model: the same tracking
        assert np.array_equal(learnt.model.cov_yuv, imported.model.cov_yuv)
    assert len(list(read_frames(rec, "cam0"))) == 5  # and the take itself after it
    assert not list((tmp_path / "out" / "background").glob(".*"))  # no temporary file left


def test_record_without_background_has_none_and_bad_duration_refused(tmp_path, rng, capsys):
    src, _ = make_session(tmp_path / "src", rng, n_frames=3, background=True)
    cfg = _config(tmp_path / "studio.toml", src.root)
    assert main(["record", "--config", str(cfg), str(tmp_path / "out"), "--pacing", "fast"]) == 0
    assert load_session(tmp_path / "out", require_calibration=False).camera("cam0").background is None
    try:
        main(["record", "--config", str(cfg), str(tmp_path / "o2"), "--background", "soon"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "duration" in capsys.readouterr().err and not (tmp_path / "o2").exists()


def test_track_warns_once_about_a_median_background():
    assert median_warning({"cam0": "video", "cam1": "video"}) is None
    line = median_warning({"cam0": "median", "cam1": "video", "cam2": "median"})
    assert "cam0, cam2" in line and "still" in line and "--background" in line and "\n" not in line
