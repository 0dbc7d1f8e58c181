"""``[tracker] method = "blobs"``: the blob track worker on camera frames, its hull records, its config."""

from __future__ import annotations


import numpy as np
import pytest

from capture.replay import ReplaySource
from capture.session import load_session
from service.config import ConfigError, parse_config
from service.flow.supervisor import plan_host
from service.offline import track_session
from service.synthetic_session import make_synthetic_session
from service.wire.bus import Inbox
from service.wire.hull import HullMessage
from service.wire.messages import FrameMessage
from service.workers.blob_track import BlobFitter, run_blob_track_worker
from service.workers.loops import run_camera_worker
from tracker.synthetic.synth import bundled_motion
from tests.support.workers import wait_for
from tests.support.files import read_jsonl

N_FRAMES = 8


def _config(method=None):
    tracker = {"host": "a"} if method is None else {"host": "a", "method": method}
    return {"studio": {"name": "s"}, "tracker": tracker,
            "camera": [{"name": "cam0", "host": "a", "backend": "opencv", "source": "0"}]}


def test_config_method_and_plan():
    assert parse_config(_config()).method == "contours"
    cfg = parse_config(_config("blobs"))
    assert cfg.method == "blobs"
    names = [s.name for s in plan_host(cfg, "studio.toml", "a")]
    assert "track" in names and "segment" not in names  # the blob tracker reads the frames itself
    assert "segment" in [s.name for s in plan_host(parse_config(_config()), "studio.toml", "a")]
    with pytest.raises(ConfigError, match="tracker.method"):
        parse_config(_config("voxels"))


@pytest.fixture(scope="module")
def hop(tmp_path_factory):
    out = tmp_path_factory.mktemp("hop_blob_worker")
    make_synthetic_session(bundled_motion("scaled_131_03"), out, cameras=4, size=(320, 240), frames=N_FRAMES,
                           n_background=10, seed=2)
    return out


def _truth(root):
    return read_jsonl(root / "ground_truth.jsonl")


def test_blob_fitter_learns_its_backgrounds_first(hop):
    session = load_session(hop)
    names = list(session.camera_names)
    fit = BlobFitter.from_session(session, replayed=names[1:], learn_frames=2,
                                  initial_params=np.asarray(_truth(hop)[0]["params"]))
    frames = {n: ReplaySource(session, n) for n in names}
    for s in frames.values():
        s.open()
    recs = []
    for k in range(3):
        msgs = {n: FrameMessage.from_image(n, k, 0, src.read().image) for n, src in frames.items()}
        recs.append(fit(k, 0, msgs))
    assert recs[0]["ok"] is False and "learning the background" in recs[0]["reason"] and names[0] in recs[0]["reason"]
    assert recs[1]["method"] == "blobs" and "learning" not in recs[1].get("reason", "")
    assert set(fit.backgrounds) == set(names)
    bad = {names[0]: FrameMessage(names[0], 9, 0, "png", (240, 320, 3), b"not a png")}
    assert "bad frame" in fit(9, 0, bad)["reason"]


def test_blob_fitter_warm_up_leaves_nothing_to_compile_for_the_live_fits(hop):
    """In a fresh process: after ``BlobFitter.warm_up`` no numba kernel gains a signature while the
    fitter fits read-only frames decoded from the wire (a missing one would compile inside a live set)."""
    import json
    import subprocess
    import sys

    code = f"""
import json, numba
import segmentation.samples, tracker.blobs.kernels, tracker.kernels
from capture.replay import ReplaySource
from capture.session import load_session
from service.wire.messages import FrameMessage
from service.workers.blob_track import BlobFitter

def counts():
    out = {{}}
    for mod in (tracker.blobs.kernels, segmentation.samples, tracker.kernels):
        for name in dir(mod):
            f = getattr(mod, name)
            if isinstance(f, numba.core.registry.CPUDispatcher):
                out[mod.__name__ + "." + name] = len(f.signatures)
    return out

session = load_session({str(hop)!r})
start = json.loads(open({str(hop / "ground_truth.jsonl")!r}).readline())["params"]
fit = BlobFitter.from_session(session, replayed=list(session.camera_names), initial_params=start)
fit.warm_up()
before = counts()
sources = {{n: ReplaySource(session, n) for n in session.camera_names}}
for s in sources.values():
    s.open()
recs = []
for k in range(4):
    msgs = {{n: FrameMessage.from_image(n, k, 0, src.read().image) for n, src in sources.items()}}
    recs.append(fit(k, 0, msgs))
print(json.dumps([before, counts(), sum("params" in r for r in recs), [r.get("reason") for r in recs]]))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after, fitted, reasons = json.loads(out.stdout.strip().splitlines()[-1])
    assert fitted == 4, reasons
    grown = {k: (before.get(k, 0), v) for k, v in after.items() if v != before.get(k, 0)}
    assert not grown, grown


@pytest.mark.slow
def test_lossless_blob_worker_equals_offline_and_publishes_hulls(hop, studio):
    """Camera worker -> blob track worker (no segment worker) in lossless mode gives exactly the offline
    ``contourcap track --method blobs --no-smooth`` poses, and one hull record per fitted set."""
    session = load_session(hop)
    names = tuple(session.camera_names)
    init = np.asarray(_truth(hop)[0]["params"])
    offline = list(track_session(session, method="blobs", initial_params=init, smooth_s=0.0))
    keys, poses = studio.keys, []
    track_s = studio.session(listen=True)
    client = studio.session()
    hulls = Inbox(client, keys.hull, HullMessage.from_bytes, mode="lossless", depth=100)
    fit = BlobFitter.from_session(session, replayed=names, initial_params=init)
    studio.start("track", run_blob_track_worker, track_s, keys, names, fit, mode="lossless",
                 stop=studio.stop, max_frames=N_FRAMES, on_pose=poses.append)
    sources = {c: ReplaySource(session, c) for c in names}
    for s in sources.values():
        s.open()
    cam = run_camera_worker(studio.session(), keys, sources, mode="lossless", window=2, stop=studio.stop,
                            encodings={n: "png" for n in names}, credit_timeout_s=60.0, startup_timeout_s=20.0)
    studio.threads[0].join(30.0)
    assert cam["processed"] == len(names) * N_FRAMES
    assert [p.frame for p in poses] == list(range(N_FRAMES))
    assert all(p.get("method") == "blobs" for p in poses)
    assert [p.get("params") for p in poses] == [pytest.approx(o["params"], abs=1e-9) for o in offline]
    got = []
    assert wait_for(lambda: got.extend(hulls.drain()) or len(got) >= N_FRAMES, 5.0)
    assert [r.message.frame_id for r in got] == list(range(N_FRAMES))
    assert all(abs(r.message.count - o["voxels"]) == 0 for r, o in zip(got, offline))
    assert studio.results["track"]["hulls"] == N_FRAMES


@pytest.mark.slow
def test_live_blob_worker_fits_the_newest_frames(hop, studio):
    """Live: a camera worker replays in real time, the blob track worker (no segment worker, no demand)
    fits complete sets of the newest frames and publishes a pose and a hull for each."""
    session = load_session(hop)
    names = tuple(session.camera_names)
    fit = BlobFitter.from_session(session, replayed=names, initial_params=np.asarray(_truth(hop)[0]["params"]))
    poses, track_s = [], studio.session(listen=True)
    client = studio.session()
    hulls = Inbox(client, studio.keys.hull, HullMessage.from_bytes, mode="lossless", depth=100)
    studio.start("track", run_blob_track_worker, track_s, studio.keys, names, fit, mode="live", set_timeout_s=0.3,
                 stop=studio.stop, on_pose=poses.append)
    sources = {c: ReplaySource(session, c, pacing="realtime") for c in names}
    for s in sources.values():
        s.open()
    cam = run_camera_worker(studio.session(), studio.keys, sources, mode="live", stop=studio.stop)
    assert cam["processed"] == len(names) * N_FRAMES
    assert wait_for(lambda: len(poses) >= 1, 20.0)
    studio.stop.set()
    studio.threads[0].join(20.0)
    assert all(p.get("method") == "blobs" for p in poses)
    assert any(p.get("cameras") == len(names) for p in poses), [p.get("cameras") for p in poses]  # late cameras: fewer
    assert len({p.frame for p in poses}) == len(poses)  # each set once
    got = []
    assert wait_for(lambda: got.extend(hulls.drain()) or len(got) >= len(poses), 5.0)
    assert {r.message.frame_id for r in got} == {p.frame for p in poses}
