"""``contourcap segment SESSION OUT`` end to end on a small synthetic session written to disk."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from capture.session import write_session_toml
from segmentation.synthetic import synthetic_scene
from service.cli import main
from tests.support.segmentation import iou


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("session")
    scene = synthetic_scene(np.random.default_rng(5), size=(320, 240), n_background=20, n_frames=6)
    (root / "cam0").mkdir()
    (root / "background").mkdir()
    for k, frame in enumerate(scene.frames):
        cv2.imwrite(str(root / "cam0" / f"{k:06d}.png"), frame)
    writer = cv2.VideoWriter(str(root / "background" / "cam0.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 25, (320, 240))
    for frame in scene.background_frames:
        writer.write(frame)
    writer.release()
    (root / "cam1").mkdir()  # a second camera without background media: median background
    for k, frame in enumerate(scene.frames):
        cv2.imwrite(str(root / "cam1" / f"{k:06d}.png"), frame)
    write_session_toml(root, name="synthetic", fps=25.0, cameras=[
        {"name": "cam0", "images": "cam0/%06d.png", "background": "background/cam0.avi"},
        {"name": "cam1", "images": "cam1/%06d.png"},
    ])
    return root, scene


def test_segment_command_writes_images_and_stats(session_dir, tmp_path, capsys):
    root, scene = session_dir
    out = tmp_path / "out"
    rc = main(["segment", str(root), str(out), "--every", "2", "--json", "--save-models"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    assert "ETA" in captured.err and "12/12" in captured.err
    stats = json.loads(captured.out)
    assert stats == json.loads((out / "stats.json").read_text())
    cam0, cam1 = stats["cameras"]["cam0"], stats["cameras"]["cam1"]
    assert cam0["frames"] == 6 and cam1["frames"] == 6
    assert cam0["background"].startswith("background media") and cam1["background"].startswith("median")
    true_fraction = scene.person_masks.mean()
    assert abs(cam0["foreground_fraction_mean"] - true_fraction) < 0.1 * true_fraction
    assert cam0["ms_per_frame_median"] > 0
    assert (out / "cam0" / "background.npz").is_file()
    written = sorted(p.name for p in (out / "cam0").glob("silhouette_*.png"))
    assert written == ["silhouette_000000.png", "silhouette_000002.png", "silhouette_000004.png"]
    for k in (0, 2, 4):
        sil = cv2.imread(str(out / "cam0" / f"silhouette_{k:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert iou(sil, scene.person_masks[k]) > 0.9
        dist = cv2.imread(str(out / "cam0" / f"dist_sil_{k:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert dist.shape == (240, 320) and (dist[sil > 0] == 0).all() and dist.max() == 48 * 4
        edges = cv2.imread(str(out / "cam0" / f"edges_{k:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert edges.any() and not edges[cv2.dilate(sil, np.ones((9, 9), np.uint8)) == 0].any()


def test_segment_command_names_bad_camera_and_roi(session_dir, tmp_path, capsys):
    root, _ = session_dir
    assert main(["segment", str(root), str(tmp_path / "o"), "--cameras", "nope", "--no-progress"]) == 2
    assert "nope" in capsys.readouterr().err
    assert main(["segment", str(root), str(tmp_path / "o"), "--roi", "1,2,3", "--no-progress"]) == 2
    assert "--roi" in capsys.readouterr().err
    assert main(["segment", str(tmp_path / "missing"), str(tmp_path / "o"), "--no-progress"]) == 2
    assert "missing" in capsys.readouterr().err
    assert main(["segment", str(root), str(tmp_path / "o"), "--max-components", "0", "--no-progress"]) == 2
    assert "--max-components" in capsys.readouterr().err
    for option, value in (("--frames", "4:2"), ("--frames", "x:3"), ("--background-frames", "0"),
                          ("--median-frames", "2"), ("--cameras", ",")):
        assert main(["segment", str(root), str(tmp_path / "o"), option, value, "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("contourcap segment: --") and option in err and "Traceback" not in err


def test_segment_command_options_reach_the_pipeline(session_dir, tmp_path, capsys):
    root, scene = session_dir
    out = tmp_path / "opts"
    rc = main(["segment", str(root), str(out), "--cameras", "cam0", "--frames", "1:3", "--every", "0",
               "--no-auto-roi", "--max-components", "1", "--no-progress", "--json"])
    assert rc == 0
    stats = json.loads(capsys.readouterr().out)
    assert list(stats["cameras"]) == ["cam0"] and stats["cameras"]["cam0"]["frames"] == 2
    assert not list((out / "cam0").glob("*.png"))
    true_fraction = scene.person_masks[1:3].mean()
    assert abs(stats["cameras"]["cam0"]["foreground_fraction_mean"] - true_fraction) < 0.1 * true_fraction


def test_background_of_another_size_names_the_camera(tmp_path, capsys):
    (tmp_path / "cam0").mkdir()
    for k in range(2):
        cv2.imwrite(str(tmp_path / "cam0" / f"{k:06d}.png"), np.full((48, 64, 3), 100, np.uint8))
    cv2.imwrite(str(tmp_path / "bg.png"), np.full((40, 64, 3), 100, np.uint8))  # 64x40, frames 64x48
    write_session_toml(tmp_path, name="s", fps=25.0,
                       cameras=[{"name": "cam0", "images": "cam0/%06d.png", "background": "bg.png"}])
    assert main(["segment", str(tmp_path), str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "camera 'cam0' frame 0" in err and "(64, 48) does not match the background model's (64, 40)" in err
