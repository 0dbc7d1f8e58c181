"""bench/real_reference.py: the reference's triangulation (no detector needed) and its comparison."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from capture.camera import Camera

_PATH = Path(__file__).resolve().parents[2] / "bench" / "real_reference.py"


@pytest.fixture(scope="module")
def rr():
    spec = importlib.util.spec_from_file_location("real_reference", _PATH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["real_reference"] = mod
    spec.loader.exec_module(mod)
    return mod


def _cameras():
    dist = (-0.35, 0.18, 0.0005, -0.0003, -0.05)  # strong barrel distortion, like the real studio
    return [Camera.look_at(f"cam{i}", (3.5 * np.cos(a), 3.5 * np.sin(a), 1.8), (0.0, 0.0, 1.0), size=(644, 486),
                           fov_deg=70.0, distortion=dist)
            for i, a in enumerate(np.radians([0.0, 80.0, 170.0, 260.0]))]


def test_triangulation_recovers_a_point_and_drops_a_wrong_view(rr):
    rng = np.random.default_rng(4)
    cams = _cameras()
    for _ in range(20):
        X = rng.uniform([-0.6, -0.6, 0.1], [0.6, 0.6, 1.8])
        uv = np.array([c.project(X) for c in cams]) + rng.normal(0, 0.5, (4, 2))
        vis = rng.uniform(0.6, 1.0, 4)
        P, used, err = rr.triangulate_joint(cams, uv, vis, min_visibility=0.5, max_reproj_px=8.0)
        assert used == [0, 1, 2, 3] and np.linalg.norm(P - X) < 0.01 and err < 2.0
        bad = uv.copy()
        bad[2] += (40.0, -25.0)  # one camera's detector is on something else
        P, used, err = rr.triangulate_joint(cams, bad, vis, min_visibility=0.5, max_reproj_px=8.0)
        assert used == [0, 1, 3] and np.linalg.norm(P - X) < 0.01
        low = vis.copy()
        low[[0, 1, 3]] = 0.2  # only one view visible enough: no point
        P, used, _ = rr.triangulate_joint(cams, uv, low, min_visibility=0.5, max_reproj_px=8.0)
        assert used == [] and np.all(np.isnan(P))


def test_compare_groups_hips_apart(rr):
    ref_joints = {j: [0.0, 0.0, 1.0] for j in rr.JOINTS}
    reference = [{"frame": 0, "joints": ref_joints}]
    pose = {j: [0.0, 0.0, 1.0] for j in rr.JOINTS}
    pose["left_knee"] = [0.1, 0.0, 1.0]        # 100 mm off
    pose["left_hip"] = [0.0, 0.05, 1.0]        # 50 mm off
    res = rr.compare(reference, [{"frame": 0, "ok": False, "joints": pose}, {"frame": 9, "joints": pose}])
    assert res["frames_compared"] == 1 and res["frames_ok"] == 0
    assert res["joint_error_mm"]["left_knee"] == pytest.approx(100.0)
    assert res["judged_mean_mm"] == pytest.approx(100.0 / len(rr.JUDGED))
    assert res["hips_mean_mm"] == pytest.approx(25.0)
    assert res["ok_only_judged_mean_mm"] is None


@pytest.mark.slow
def test_reference_on_real_footage_is_consistent_across_views(rr, shared_data, tmp_path):
    """uu_studio, 5 frame sets: every judged joint triangulated from >= 3 views, a few px reprojection."""
    try:
        import mediapipe.python.solutions.pose  # noqa: F401
    except ImportError:
        pytest.skip("the [eval] extra (mediapipe) is not installed")
    from capture.session import load_session
    from capture.uu_studio import import_uu_studio

    out = tmp_path / "uu"
    import_uu_studio(shared_data / "uu_studio", out)
    records, timing = rr.build_reference(load_session(out), range(0, 5), 1, static=False, min_visibility=0.5,
                                         max_reproj_px=12.0, progress=False)
    assert len(records) == 5 and timing["sets"] == 5
    stats = rr.reference_stats(records)
    assert all(stats["coverage_percent"][j] == 100.0 for j in rr.JUDGED)
    assert stats["mean_views"] >= 3.0 and stats["median_reproj_px"] < 3.0
    for r in records:  # a seated subject: knees above the floor, ankles below the knees, head on top
        z = {j: r["joints"][j][2] for j in rr.JOINTS if r["joints"][j] is not None}
        assert 0.2 < z["left_knee"] < 0.8 and z["left_ankle"] < z["left_knee"] and z["head"] > z["neck"] > z["left_hip"]
