"""Synthetic sessions (``service.synthetic_session``): files, decodable videos, calibration, ground truth
inside the true silhouettes, the CLI."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from capture.calibration import load_calibration
from capture.session import load_session
from service.cli import main as cli_main
from service.wire.records import PoseRecord
from tracker.body.kinematics import forward
from tracker.body.model import load_model
from tracker.imaging.render import render_silhouettes
from service.synthetic_session import make_synthetic_session
from tracker.synthetic.synth import bundled_motion
from tests.support.files import read_video

N_FRAMES, N_CAMS, SIZE, N_BG = 5, 3, (320, 240), 10


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth") / "s1"
    calls = []
    make_synthetic_session(
        bundled_motion("scaled_131_03"), out, cameras=N_CAMS, size=SIZE, frames=N_FRAMES, start_s=2.0,
        masks=True, n_background=N_BG, seed=3, progress=lambda d, n: calls.append((d, n)),
    )  # fmt: skip
    assert calls == [(k + 1, N_FRAMES) for k in range(N_FRAMES)]
    return out


def test_files_and_videos(session):
    for name in ("session.toml", "calibration.toml", "ground_truth.jsonl"):
        assert (session / name).is_file()
    for i in range(N_CAMS):
        frames = read_video(session / f"cam{i}.avi")
        assert len(frames) == N_FRAMES
        assert all(f.shape == (SIZE[1], SIZE[0], 3) for f in frames)
        assert len(read_video(session / "background" / f"cam{i}.avi")) == N_BG
        assert len(list((session / "masks" / f"cam{i}").glob("*.png"))) == N_FRAMES


def test_session_and_calibration_load(session):
    s = load_session(session)
    assert s.camera_names == tuple(f"cam{i}" for i in range(N_CAMS))
    assert s.fps == 30.0
    assert 1.4 < s.height_m < 1.65
    cams = load_calibration(session / "calibration.toml")
    assert [c.size for c in cams] == [SIZE] * N_CAMS
    centres = np.array([c.center for c in cams])
    radii = np.linalg.norm(centres[:, :2] - centres[:, :2].mean(axis=0), axis=1)
    assert np.allclose(radii, radii[0]) and radii[0] >= 4.0 - 1e-9  # a ring around the subject
    for c in cams:
        assert s.camera(c.name).background is not None


def test_ground_truth_inside_true_silhouettes(session):
    cams = load_calibration(session / "calibration.toml")
    lines = (session / "ground_truth.jsonl").read_text().splitlines()
    assert len(lines) == N_FRAMES
    height = load_session(session).height_m
    model = load_model("knossow40", height_m=height)
    kernel = np.ones((3, 3), np.uint8)
    for k, line in enumerate(lines):
        rec = PoseRecord.from_dict(json.loads(line))
        assert rec.frame == k and rec.ok and rec.timestamp_ns == round(k * 1e9 / 30)
        assert rec.get("model") == "knossow40" and len(rec.get("params")) == model.n_params
        joints = rec.joints
        assert set(joints) >= {"pelvis", "head", "left_wrist", "right_ankle"}
        params = np.array(rec.get("params"))
        pose = forward(model, params)
        sils = render_silhouettes(model, pose, cams)
        for c, sil in zip(cams, sils):
            mask = cv2.imread(str(session / "masks" / c.name / f"{k:06d}.png"), cv2.IMREAD_GRAYSCALE)
            assert np.array_equal(mask, sil)  # the stored masks are the model's silhouettes
            grown = cv2.dilate(mask, kernel) > 0
            uv = np.rint(c.project(np.array(list(joints.values())))).astype(int)
            assert np.all(c.in_image(uv)), f"frame {k} {c.name}: a joint is outside the image"
            inside = grown[uv[:, 1], uv[:, 0]]
            assert inside.all(), f"frame {k} {c.name}: joints {np.array(list(joints))[~inside]} off the silhouette"


def test_video_shows_the_body_where_the_mask_says(session):
    """Frame minus the (noisy) background: big inside the mask, noise-sized away from body and shadow."""
    for i in range(N_CAMS):
        frame = read_video(session / f"cam{i}.avi")[2].astype(float)
        bg = read_video(session / "background" / f"cam{i}.avi")[0].astype(float)
        mask = cv2.imread(str(session / "masks" / f"cam{i}" / "000002.png"), cv2.IMREAD_GRAYSCALE) > 0
        diff = np.abs(frame - bg).max(axis=2)
        far = cv2.dilate(mask.astype(np.uint8), np.ones((61, 61), np.uint8)) == 0  # beyond body and shadow
        assert np.median(diff[mask]) > 25
        # two independent N(0, 2) per channel: |a - b| max over 3 channels is rarely above 12
        assert np.mean(diff[far] > 12) < 0.01
        # robust sigma of the difference (a long shadow may still reach into `far`): sqrt(2) * 2 = 2.83
        d = (frame - bg)[far]
        sigma = 1.4826 * np.median(np.abs(d - np.median(d)))
        assert 2.3 < sigma < 3.4


def test_png_codec_and_cli(tmp_path, capsys):
    out = tmp_path / "cli"
    rc = cli_main([
        "synth", f"bundled:scaled_131_01", str(out), "--cameras", "2", "--size", "160x120", "--frames", "2",
        "--codec", "png", "--no-shadow", "--background-frames", "3", "--seed", "5",
    ])  # fmt: skip
    assert rc == 0
    s = load_session(out)
    assert s.camera_names == ("cam0", "cam1")
    assert sorted(p.name for p in (out / "cam0").glob("*.png")) == ["000000.png", "000001.png"]
    img = cv2.imread(str(out / "cam1" / "000001.png"))
    assert img.shape == (120, 160, 3)
    assert len(read_video(out / "background" / "cam0.avi")) == 3
    assert "2/2 frames" in capsys.readouterr().err
    # a session already there is not overwritten without --force
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    assert cli_main(["synth", "bundled:scaled_131_01", str(out), "--cameras", "1", "--size", "32x32", "--frames", "1"]) == 2
    assert f"{out}: exists and is not an empty folder" in capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before


def test_cli_errors(tmp_path, capsys):
    assert cli_main(["synth", str(tmp_path / "missing.bvh"), str(tmp_path / "o")]) == 2
    assert "missing.bvh" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()  # nothing created for a failed run
    with pytest.raises(SystemExit):
        cli_main(["synth", "x.bvh", str(tmp_path / "o"), "--size", "800by600"])
    assert "--size must be WIDTHxHEIGHT" in capsys.readouterr().err


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="codec"):
        make_synthetic_session(bundled_motion(), tmp_path / "x", codec="h264")
    with pytest.raises(ValueError, match="noise"):
        make_synthetic_session(bundled_motion(), tmp_path / "x", noise=-1)
    with pytest.raises(FileNotFoundError, match="available"):
        bundled_motion("nope")


def test_replay_reads_the_session(session):
    """The session is what capture.replay reads: frame ids 0..K-1 at k / fps, and the backgrounds."""
    from capture.replay import read_frames

    s = load_session(session)
    frames = list(read_frames(s, "cam1"))
    assert [f.frame_id for f in frames] == list(range(N_FRAMES))
    assert [f.timestamp_ns for f in frames] == [round(k * 1e9 / 30) for k in range(N_FRAMES)]
    assert np.array_equal(frames[3].image, read_video(session / "cam1.avi")[3])
    assert len(list(read_frames(s, "cam1", background=True))) == N_BG


def test_fitted_segments_reach_session_toml(tmp_path):
    out = make_synthetic_session(bundled_motion(), tmp_path / "seg", cameras=1, size=(64, 48), frames=1,
                                 n_background=1, fit_segments=True, noise=0.0)  # fmt: skip
    s = load_session(out)
    assert set(s.segment_lengths) == {"thigh", "shank", "upper_arm", "forearm"}
    rec = json.loads((out / "ground_truth.jsonl").read_text())
    model = load_model("knossow40", height_m=s.height_m, segment_lengths=s.segment_lengths)
    joints = forward(model, np.array(rec["params"]))
    from tracker.body.kinematics import joint_centres

    for name, xyz in joint_centres(model, joints).items():
        assert np.allclose(rec["joints"][name], xyz)  # the session alone rebuilds the ground-truth model


def test_video_sink_check_counts_the_frames_stored(tmp_path):
    from service.synthetic_session import _Sink

    sink = _Sink(tmp_path, "cam0", "ffv1", 30.0, (32, 24))
    for _ in range(3):
        sink.write(np.full((24, 32, 3), 100, np.uint8))
    sink.close()
    sink.check()  # all 3 stored
    sink.frame = 4  # as if a write had been lost
    with pytest.raises(OSError, match=r"cam0.avi: holds 3 of the 4 frames written"):
        sink.check()
