"""`contourcap demo` plumbing end to end (workers as processes, real segmentation over zenoh, a
deterministic stand-in for the tracker): every frame arrives, in order, with exactly the values the
offline segmentation gives; summary, poses.jsonl and .rrd are written.  Live: poses over the replay
window, the tracker's demand counters, images of the first camera only."""

from __future__ import annotations

import collections
import json

import numpy as np
import pytest

pytest.importorskip("tracker.synthetic.synth")

from capture.replay import iter_frame_sets  # noqa: E402
from capture.session import load_session  # noqa: E402
from segmentation.pipeline import segment_frame  # noqa: E402
from service.workers.components import chamfer_to_message  # noqa: E402
from service.demo import DemoOptions, decoded_clip_mb, run_demo, session_frames  # noqa: E402
from service.offline import background_models  # noqa: E402

from tests.support.plugins import fitter  # noqa: E402


def test_demo_lossless_equals_offline_segmentation(tmp_path):
    opts = DemoOptions(cameras=2, size=(160, 120), frames=6, fps=30.0, out_dir=tmp_path / "out",
                       cache_dir=tmp_path / "cache", timeout_s=120.0,
                       fit_plugin="tests.support.plugins:fitter_factory")
    summary = run_demo(opts, progress=lambda m: None)
    assert summary.frames == 10 and summary.ok == 10  # 6 frames of motion forward, then 4 back
    poses = [json.loads(line) for line in (tmp_path / "out" / "poses.jsonl").read_text().splitlines()]
    session = load_session(summary.session)
    models, _ = background_models(session, list(session.camera_names))
    offline = []
    for fid, group in iter_frame_sets(session):
        msgs = {c: chamfer_to_message(c, fid, f.timestamp_ns, segment_frame(models[c], f.image).chamfer)
                for c, f in group.items()}
        offline.append(fitter(fid, next(iter(group.values())).timestamp_ns, msgs))
    assert [p["frame"] for p in poses] == [o["frame"] for o in offline]
    assert [p["params"] for p in poses] == [o["params"] for o in offline]
    assert summary.latency_ms_p50 is not None and summary.latency_ms_p99 >= summary.latency_ms_p50 > 0
    assert summary.mean_joint_error_m is not None and np.isfinite(summary.mean_joint_error_m)
    assert (tmp_path / "out" / "demo.rrd").stat().st_size > 0
    assert summary.poses_per_s is None and summary.demand_timeouts is None and summary.missing_cameras is None


def test_live_demo_cameras_hold_the_clip_decoded_only_when_it_fits(tmp_path):
    import argparse

    from service.commands.worker import add_args
    from service.config import parse_config
    from service.flow.supervisor import plan_host

    opts = DemoOptions()
    assert session_frames(opts) == 178 and session_frames(DemoOptions(bounce=False)) == 90
    assert decoded_clip_mb(opts) == pytest.approx(178 * 6 * 320 * 240 * 3 / 1e6)  # ~246 MB: fits the default
    assert decoded_clip_mb(DemoOptions(size=(800, 600))) > opts.live_preload_mb  # 1.5 GB: decoded while streaming
    cfg_path = tmp_path / "studio.toml"
    cfg = parse_config({"studio": {"name": "s"}, "tracker": {"host": "demo"},
                        "camera": [{"name": "cam0", "host": "demo", "backend": "opencv", "source": "0"}]})
    parser = argparse.ArgumentParser()
    add_args(parser)
    for preload in (False, True):
        specs = plan_host(cfg, str(cfg_path), "demo", loop_replay=True, preload_replay=preload)
        camera = next(s for s in specs if s.name.startswith("camera"))
        args = parser.parse_args(list(camera.argv[3:]))  # after python -m service.commands.worker
        assert args.loop and args.preload == preload


def test_demo_live_summary_and_rrd(tmp_path):
    rrchunk = pytest.importorskip("rerun.chunk")
    opts = DemoOptions(cameras=2, size=(160, 120), frames=30, fps=30.0, out_dir=tmp_path / "out",
                       cache_dir=tmp_path / "cache", timeout_s=120.0, delivery="live", image_every=3,
                       live_start_delay_s=4.0, live_duration_s=4.0, live_image_cameras=1,
                       fit_plugin="tests.support.plugins:fitter_factory")
    assert DemoOptions().live_image_cameras == 0  # live images only when asked for
    summary = run_demo(opts, progress=lambda m: None)
    assert summary.frames > 0
    # poses over the whole 4 s replay window (not between the first and the last pose)
    assert summary.poses_per_s == pytest.approx(summary.frames / 4.0, rel=0.02)
    assert summary.demand_timeouts is not None and summary.demand_timeouts >= 0
    assert summary.missing_cameras is not None and summary.missing_cameras >= 0
    rows = collections.Counter()
    for chunk in rrchunk.RrdReader(tmp_path / "out" / "demo.rrd").stream():
        rows[str(chunk.entity_path)] += chunk.num_rows
    # one camera's images and silhouettes (live_image_cameras)
    assert rows["/world/cameras/cam0/image"] >= 1 and rows["/world/cameras/cam1/image"] == 0
    assert rows["/world/cameras/cam0/silhouette"] >= 1 and rows["/world/cameras/cam1/silhouette"] == 0
    assert summary.replay_ns[0] < summary.replay_ns[1]
    assert rows["/world/skeleton"] >= 1 + 1  # poses + the static annotation context


def _pose_table(live: list[dict], offline: list[dict]) -> str:
    """Per frame, live vs offline: cameras, iterations, ok/reason, rms_px and max |params diff|."""
    def side(r: dict) -> str:
        rms = r.get("rms_px")
        return (f"cameras {r.get('cameras')} it {r.get('iterations')} "
                + ("ok" if r.get("ok") else f"NOT ok ({r.get('reason')})")
                + (f" rms {rms:.4f}" if rms is not None else ""))

    lines = []
    for p, o in zip(live, offline):
        both = p.get("params") and o.get("params") and len(p["params"]) == len(o["params"])
        d = float(np.max(np.abs(np.subtract(p["params"], o["params"])))) if both else float("nan")
        lines.append(f"frame {p.get('frame')}: live {side(p)} | offline {side(o)} | max |diff| {d:.3g}")
    return "\n".join(lines)


def _equal(p: dict, o: dict, atol: float) -> bool:
    keys = ("frame", "ok", "cameras", "iterations")
    if any(p.get(k) != o.get(k) for k in keys) or p.get("joints", {}).keys() != o.get("joints", {}).keys():
        return False
    if "params" not in p or "params" not in o:
        return "params" not in p and "params" not in o
    names = list(o["joints"])
    return (np.allclose(p["params"], o["params"], rtol=0, atol=atol)
            and np.allclose([p["joints"][k] for k in names], [o["joints"][k] for k in names], rtol=0, atol=atol))


@pytest.mark.slow
def test_demo_lossless_real_tracker_equals_offline(tmp_path):
    """The contract of DESIGN.md: lossless replay over zenoh gives the same poses as `contourcap track`
    fitting every frame once, unsmoothed (`--no-retrack`: by default offline also fits refused stretches again
    backwards and smooths the poses over a centred window, which a live tracker cannot).

    Under CPU load this failed now and then (a set released after the lossless set timeout without a
    camera: a camera worker closed its zenoh session right after its last put, and frames a slow
    segment worker had not read yet were lost); the message gives per frame what each side used."""
    from service.offline import track_session

    opts = DemoOptions(cameras=3, size=(200, 150), frames=4, fps=30.0, out_dir=tmp_path / "out",
                       cache_dir=tmp_path / "cache", timeout_s=300.0, bounce=False)
    summary = run_demo(opts, progress=lambda m: None)
    live = [json.loads(line) for line in (tmp_path / "out" / "poses.jsonl").read_text().splitlines()]
    offline = list(track_session(load_session(summary.session), retrack=False))  # unsmoothed: as live
    table = _pose_table(live, offline)
    assert [p["frame"] for p in live] == [o["frame"] for o in offline] == [0, 1, 2, 3], table
    # the first frame may be held by the front/back guard (tracker.fitting.hypotheses) while it weighs the
    # initialised pose against its mirror
    assert all((o["ok"] or (o["frame"] == 0 and o["reason"].startswith("front/back ambiguous")))
               and o["cameras"] == 3 for o in offline), table
    # Equal to rounding: the last bits (~1e-15) were once reported to differ from the workers' after other
    # tests in this process; in 116 stress runs and a whole-suite run they were identical (max |diff| 0).
    # 1e-9 (nanometres, nanoradians) still catches any real difference (a camera missing from a set moves
    # the pose by 0.2-0.5 rad).
    bad = [p["frame"] for p, o in zip(live, offline) if not _equal(p, o, atol=1e-9)]
    assert not bad, f"live != offline at frames {bad}:\n{table}"
