"""`contourcap stream vmc --replay`: a python-osc server on 127.0.0.1 receives a bone set for >= 99 % of
the ok frames, none for the lost ones (/VMC/Ext/OK says so); bone quaternions are unit; Hips is at
the pelvis after the axis change (Unity: (x, y, z) -> (-y, z, x)) within 1 mm; and forward kinematics
over Unity's humanoid hierarchy with the received local rotations and offsets puts the shoulders,
elbows, wrists, hips and knees where the records have them."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

osc_server = pytest.importorskip("pythonosc.osc_server")
pytest.importorskip("tracker.synthetic.retarget")

from pythonosc.dispatcher import Dispatcher  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from tests.support.outputs import FIRST_ID, FPS, make_take  # noqa: E402
from service.cli import main  # noqa: E402
from service.export import write_pose_records  # noqa: E402

TO_UNITY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
UNITY_PARENT = {  # Unity's HumanBodyBones hierarchy (Neck/UpperChest may be absent)
    "Spine": "Hips", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    "LeftShoulder": "Chest", "LeftUpperArm": "LeftShoulder", "LeftLowerArm": "LeftUpperArm",
    "LeftHand": "LeftLowerArm", "RightShoulder": "Chest", "RightUpperArm": "RightShoulder",
    "RightLowerArm": "RightUpperArm", "RightHand": "RightLowerArm", "LeftUpperLeg": "Hips",
    "LeftLowerLeg": "LeftUpperLeg", "LeftFoot": "LeftLowerLeg", "RightUpperLeg": "Hips",
    "RightLowerLeg": "RightUpperLeg", "RightFoot": "RightLowerLeg",
}
JOINT_BONE = {"spine": "Chest", "left_shoulder": "LeftUpperArm", "left_elbow": "LeftLowerArm",
              "left_wrist": "LeftHand", "right_shoulder": "RightUpperArm", "right_elbow": "RightLowerArm",
              "right_wrist": "RightHand", "left_knee": "LeftLowerLeg", "right_knee": "RightLowerLeg"}
# (the upper legs start at the thighs' origins, the model's pivots; the reported hip joint centres
# are points of the pelvis inside them: tracker.body.model.PIVOT_PART)


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    records, truth = make_take()
    path = tmp_path_factory.mktemp("take") / "poses.jsonl"
    write_pose_records(path, records)
    return path, records, truth


def _receive(argv_tail):
    """Run `stream vmc` against a local OSC server; returns bundles as lists of (address, args)."""
    msgs = []
    disp = Dispatcher()
    disp.set_default_handler(lambda address, *args: msgs.append((address, args)))
    server = osc_server.ThreadingOSCUDPServer(("127.0.0.1", 0), disp)
    server.daemon_threads = False
    port = server.server_address[1]
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        assert main(["stream", "vmc", "--to", f"127.0.0.1:{port}", *argv_tail]) == 0
        time.sleep(0.5)
    finally:
        server.shutdown()
        server.server_close()
    bundles, cur = [], None
    for address, args in msgs:  # every bundle starts with /VMC/Ext/OK
        if address == "/VMC/Ext/OK":
            cur = []
            bundles.append(cur)
        if cur is not None:
            cur.append((address, args))
    return bundles


def _fk(bones):
    """World positions and rotations of Unity bones from local positions/rotations (Hips is the root)."""
    pos, rot = {}, {}
    for name in ["Hips", *UNITY_PARENT]:
        if name not in bones:
            continue
        p, q = bones[name]
        R = Rotation.from_quat(q).as_matrix()
        par = UNITY_PARENT.get(name)
        while par is not None and par not in bones:
            par = UNITY_PARENT.get(par)
        if par is None:
            pos[name], rot[name] = np.asarray(p), R
        else:
            pos[name] = pos[par] + rot[par] @ np.asarray(p)
            rot[name] = rot[par] @ R
    return pos


def test_vmc_replay_bones_for_ok_frames(take, capsys):
    path, records, truth = take
    height = f"{truth['model'].height_m!r}"
    bundles = _receive(["--replay", str(path), "--rate", "4", "--smooth", "off", "--height-m", height])
    assert "sent 82 poses (3 not ok" in capsys.readouterr().out
    by_frame = {}
    for b in bundles:
        (t,) = dict(b)["/VMC/Ext/T"]
        by_frame[FIRST_ID + int(round(t * FPS))] = b
    ok = [r for r in records if r.ok]
    with_bones = [r for r in ok if any(a == "/VMC/Ext/Bone/Pos" for a, _ in by_frame.get(r.frame, ()))]
    assert len(with_bones) >= 0.99 * len(ok)
    for r in records:
        if not r.ok and r.frame in by_frame:
            b = by_frame[r.frame]
            assert dict(b)["/VMC/Ext/OK"] == (1, 3, 0, 0) and not any(a.endswith("Bone/Pos") for a, _ in b)
    worst_hips = worst_fk = 0.0
    for r in with_bones:
        b = by_frame[r.frame]
        assert dict(b)["/VMC/Ext/OK"] == (1, 3, 0, 1)
        assert dict(b)["/VMC/Ext/Root/Pos"] == ("root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
        bones = {args[0]: (np.array(args[1:4]), np.array(args[4:8])) for a, args in b if a == "/VMC/Ext/Bone/Pos"}
        assert len(bones) == truth["model"].n_parts
        q = np.array([v[1] for v in bones.values()])
        np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-6)
        joints = r.get("joints")
        worst_hips = max(worst_hips, np.abs(bones["Hips"][0] - TO_UNITY @ joints["pelvis"]).max())
        pos = _fk(bones)
        for joint, bone in JOINT_BONE.items():
            worst_fk = max(worst_fk, np.linalg.norm(pos[bone] - TO_UNITY @ joints[joint]))
    assert worst_hips < 0.001
    assert worst_fk < 0.001  # float32 OSC arguments


def test_vmc_replay_loop_keeps_time_running(take):
    path, records, _ = take
    bundles = _receive(["--replay", str(path), "--loop", "--rate", "10", "--count", "200"])
    times = [dict(b)["/VMC/Ext/T"][0] for b in bundles]
    assert 190 <= len(times) <= 200 and all(np.diff(times) > 0)  # time keeps running across the loops (UDP)
    assert times[-1] > 2 * 90 / FPS  # 200 poses: the third pass over the 90-frame take
    assert max(times) <= (2 * 90 + records[200 - 2 * len(records) - 1].frame - FIRST_ID) / FPS + 1e-4


def test_vmc_default_smoothing_and_bad_address(take, capsys):
    path, records, _ = take
    bundles = _receive(["--replay", str(path), "--rate", "8"])  # one-euro by default
    assert len([b for b in bundles if any(a.endswith("Bone/Pos") for a, _ in b)]) >= 0.99 * sum(r.ok for r in records)
    assert "smoothing one-euro" in capsys.readouterr().out
    assert main(["stream", "vmc", "--to", "nohostport", "--replay", str(path)]) == 2
    assert "HOST:PORT" in capsys.readouterr().err


def test_vmc_live_from_the_studio_pose_key(take):
    """Live mode: poses published on a zenoh peer's pose key reach the Marionette."""
    from service.wire.bus import Keys, ZenohSettings, declare_publisher, free_port, open_session

    _, records, _ = take
    port, stop = free_port(), threading.Event()

    def publish():
        s = open_session(ZenohSettings.loopback(port, listen=True))
        pub = declare_publisher(s, Keys("vmc1").pose)
        k = 0
        while not stop.is_set():
            pub.put(records[k % len(records)].to_bytes())
            k += 1
            time.sleep(0.01)
        s.close()

    t = threading.Thread(target=publish, daemon=True)
    t.start()
    try:
        bundles = _receive(["--connect", f"tcp/127.0.0.1:{port}", "--studio", "vmc1", "--count", "20"])
    finally:
        stop.set()
        t.join(5)
    assert len(bundles) == 20
    assert sum(any(a.endswith("Bone/Pos") for a, _ in b) for b in bundles) >= 15
