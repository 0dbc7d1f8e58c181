"""``contourcap track`` end to end on a small synthetic session (videos → segmentation → tracker)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from service.cli import main
from service.synthetic_session import make_synthetic_session
from tracker.synthetic.synth import bundled_motion
from tests.support.files import read_jsonl

N_FRAMES = 8


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("hop")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=4, size=(640, 480), frames=N_FRAMES,
                           n_background=10, seed=3)
    return out


def _mpjpe_mm(records, truth):
    errs = []
    for rec in records:
        g = truth[rec["frame"]]["joints"]
        errs.append(np.mean([np.linalg.norm(np.subtract(rec["joints"][k], g[k])) for k in g]))
    return 1e3 * float(np.mean(errs))


def test_track_session_from_known_start(session, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    rc = main(["track", str(session), "--out", str(out), "--initial-pose", str(session / "ground_truth.jsonl")])
    assert rc == 0
    recs = read_jsonl(out)
    truth = read_jsonl(session / "ground_truth.jsonl")
    assert [r["frame"] for r in recs] == list(range(N_FRAMES))
    assert all(r["ok"] for r in recs), [r.get("reason") for r in recs if not r["ok"]]
    assert all(r["model"] == "knossow40" and r["cameras"] == 4 for r in recs)
    assert _mpjpe_mm(recs, truth) < 30.0
    assert np.median([r["rms_px"] for r in recs]) < 3.0
    err = capsys.readouterr().err
    assert "background models: cam0=video" in err
    summary = json.loads(err.split("summary: ")[1].splitlines()[0])
    assert summary["frames"] == N_FRAMES and summary["ok"] == N_FRAMES and summary["lost"] == 0
    assert summary["median_iterations"] >= 1 and summary["fps"] > 0


def test_track_options_frames_cameras_solver(session, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    gt = str(session / "ground_truth.jsonl")
    rc = main(["track", str(session), "--out", str(out), "--initial-pose", gt, "--frames", "0:3",
               "--cameras", "cam0,cam1,cam3", "--no-sliding", "--solver", "lsq"])
    assert rc == 0
    recs = read_jsonl(out)
    assert [r["frame"] for r in recs] == [0, 1, 2]
    assert all(r["cameras"] == 3 for r in recs)
    assert _mpjpe_mm(recs, read_jsonl(session / "ground_truth.jsonl")) < 40.0


def test_track_bad_input_is_one_clear_error(session, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    assert main(["track", str(tmp_path / "nope"), "--out", str(out)]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["track", str(session), "--out", str(out), "--frames", "5"]) == 2
    assert "--frames" in capsys.readouterr().err
    assert main(["track", str(session), "--out", str(out), "--cameras", "cam0,cam9"]) == 2
    assert "cam9" in capsys.readouterr().err
    bad = tmp_path / "bad.jsonl"
    bad.write_text('{"params": [1, 2]}\n')
    assert main(["track", str(session), "--out", str(out), "--initial-pose", str(bad)]) == 2
    assert "--initial-pose" in capsys.readouterr().err


def test_background_from_temporal_median_when_no_background_video(session, tmp_path):
    """Without background videos the model is the temporal median of the session's frames."""
    import shutil

    from capture.session import load_session
    from service.offline import background_models

    copy = tmp_path / "nobg"
    shutil.copytree(session, copy, ignore=shutil.ignore_patterns("background"))
    toml = copy / "session.toml"
    toml.write_text("\n".join(ln for ln in toml.read_text().splitlines() if not ln.startswith("background")))
    sess = load_session(copy)
    models, how = background_models(sess, ["cam0", "cam1"], median_frames=5)
    assert how == {"cam0": "median", "cam1": "median"}
    ref, _ = background_models(load_session(session), ["cam0"])
    # the person moves little in 8 frames, so compare away from them: the image's top rows (room)
    diff = np.abs(models["cam0"].mean_yuv[:60] - ref["cam0"].mean_yuv[:60])
    assert float(np.median(diff)) < 2.0
