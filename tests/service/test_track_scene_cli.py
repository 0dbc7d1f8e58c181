"""``contourcap track``'s real-scene options: ignore regions, and the note when a take has no empty-room video."""

from __future__ import annotations

import json
import shutil

import pytest

from service.cli import main
from tracker.synthetic.synth import bundled_motion


from service.synthetic_session import make_synthetic_session


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("hop")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=4, size=(320, 240), frames=4,
                           n_background=5, seed=3)
    return out


def test_bad_ignore_regions_are_one_clear_error(session, tmp_path, capsys):
    out = tmp_path / "p.jsonl"
    gt = str(session / "ground_truth.jsonl")
    assert main(["track", str(session), "--out", str(out), "--initial-pose", gt, "--ignore-region", "cam0:1,2,3"]) == 2
    assert "expected CAMERA:x,y,w,h" in capsys.readouterr().err
    assert main(["track", str(session), "--out", str(out), "--initial-pose", gt, "--ignore-region", "cam9:1,2,3,4"]) == 2
    assert "unknown camera" in capsys.readouterr().err
    toml = session / "session.toml"
    bad = tmp_path / "bad"
    shutil.copytree(session, bad)
    (bad / "session.toml").write_text(toml.read_text().replace('name = "cam0"', 'name = "cam0"\nignore = [[1, 2]]', 1))
    assert main(["track", str(bad), "--out", str(out), "--initial-pose", gt]) == 2
    assert "ignore" in capsys.readouterr().err


def test_an_ignore_region_over_a_whole_camera_leaves_it_out(session, tmp_path):
    out = tmp_path / "p.jsonl"
    rc = main(["track", str(session), "--out", str(out), "--initial-pose", str(session / "ground_truth.jsonl"),
               "--ignore-region", "cam0:0,0,320,240"])
    assert rc == 0
    records = [json.loads(line) for line in out.read_text().splitlines() if line.strip()]
    assert [r["cameras"] for r in records] == [3, 3, 3, 3]


def test_a_take_without_background_videos_says_once_what_to_record(session, tmp_path, capsys):
    nobg = tmp_path / "nobg"
    shutil.copytree(session, nobg, ignore=shutil.ignore_patterns("background"))
    toml = nobg / "session.toml"
    toml.write_text("\n".join(ln for ln in toml.read_text().splitlines() if not ln.startswith("background")))
    rc = main(["track", str(nobg), "--out", str(tmp_path / "p.jsonl"), "--initial-pose",
               str(session / "ground_truth.jsonl")])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert err.count("no background plate") == 1 and "empty room" in err and "stays still" in err
