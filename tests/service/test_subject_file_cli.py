"""Subject files in the offline pipeline: ``track --subject``, session.toml ``[subject] file``,
``calibrate subject`` input checks."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from capture.session import SessionError, load_session
from service.cli import main
from service.offline import session_model
from service.synthetic_session import make_synthetic_session
from tracker.body.model import load_model
from tracker.body.subject import Subject, write_subject
from tracker.synthetic.synth import bundled_motion


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("hop")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=4, size=(320, 240), frames=3,
                           n_background=5, seed=3)
    return out


def _with_subject_line(session, tmp_path, line: str):
    root = tmp_path / "s"
    shutil.copytree(session, root)
    toml = root / "session.toml"
    text = toml.read_text()
    if "[subject]\n" in text:
        toml.write_text(text.replace("[subject]\n", f"[subject]\n{line}\n", 1))
    else:
        head, rest = text.split("[[camera]]", 1)
        toml.write_text(head + f"[subject]\n{line}\n\n[[camera]]" + rest)
    return root


def test_session_subject_file_sizes_the_model(session, tmp_path):
    root = _with_subject_line(session, tmp_path, 'file = "subject.toml"')
    write_subject(root / "subject.toml", Subject("knossow40", 1.8, {"thigh": 0.5}, "test"))
    body = session_model(load_session(root))
    ref = load_model("knossow40", height_m=1.8, segment_lengths={"thigh": 0.5})
    np.testing.assert_allclose(body.offset, ref.offset)
    assert not np.allclose(body.offset, load_model("knossow40", height_m=1.8).offset)


def test_session_subject_file_missing_is_one_clear_error(session, tmp_path):
    root = _with_subject_line(session, tmp_path, 'file = "nobody.toml"')
    with pytest.raises(SessionError, match="nobody.toml"):
        load_session(root)


def test_track_subject_bad_file_is_one_clear_error(session, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    assert main(["track", str(session), "--out", str(out), "--subject", str(tmp_path / "none.toml")]) == 2
    assert "none.toml" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text("[subject]\n[subject.segment_lengths]\ntail = 0.3\n")
    assert main(["track", str(session), "--out", str(out), "--subject", str(bad)]) == 2
    assert "tail" in capsys.readouterr().err


def test_calibrate_subject_bad_input_is_one_clear_error(session, tmp_path, capsys):
    out = tmp_path / "subject.toml"
    assert main(["calibrate", "subject", str(session), "--frames", "2", "--out", str(out)]) == 2
    assert "--frames" in capsys.readouterr().err
    assert main(["calibrate", "subject", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert "nope" in capsys.readouterr().err
    assert not out.exists()


def test_calibrate_subject_uses_the_session_props(session, tmp_path, monkeypatch, capsys):
    """The session's ``[[prop]]`` boxes reach the scene tracker that ``calibrate subject`` runs (a chair
    left in the silhouettes would be fitted as body and inflate the radii)."""
    import service.commands.calibrate_subject as cs

    root = tmp_path / "s"
    shutil.copytree(session, root)
    with open(root / "session.toml", "a") as f:
        f.write("\n[[prop]]\nbox = [0.5, 0.5, 0.0, 0.9, 0.9, 0.45]\n")
    seen = {}

    class Stop(ValueError):
        pass

    def fake_scene(tracker, backgrounds, **kw):
        seen.update(kw)
        raise Stop("stopped after the scene tracker was made")

    monkeypatch.setattr(cs, "SceneTracker", fake_scene)
    assert main(["calibrate", "subject", str(root), "--frames", "0:3", "--out", str(tmp_path / "sub.toml")]) == 2
    assert "stopped after" in capsys.readouterr().err
    assert len(seen["props"]) == 1
    np.testing.assert_allclose(np.r_[seen["props"][0].lo, seen["props"][0].hi], [0.5, 0.5, 0.0, 0.9, 0.9, 0.45])
