"""Clients: `echo` prints live poses from a real zenoh peer; `export` writes a BVH from JSONL."""

from __future__ import annotations

import argparse
import json
import threading
import time

import pytest

from service.wire.bus import Keys, ZenohSettings, declare_publisher, free_port, open_session
from service.wire.records import PoseRecord


def _args(module, argv):
    parser = argparse.ArgumentParser()
    module.add_args(parser)
    return parser.parse_args(argv)


def _publish(port, studio, n, stop):
    s = open_session(ZenohSettings.loopback(port, listen=True))
    pub = declare_publisher(s, Keys(studio).pose)
    k = 0
    while not stop.is_set():
        rec = {"frame": k, "timestamp_ns": k * 20_000_000, "ok": k % 3 != 2, "cameras": 4,
               "joints": {"pelvis": [0.1, 0.2, 0.9]}, "rms_px": 1.25, "latency_ms": 12.5}
        if not rec["ok"]:
            rec["reason"] = "lost: test"
        pub.put(PoseRecord.from_dict(rec).to_bytes())
        k += 1
        time.sleep(0.02)
    s.close()


@pytest.mark.parametrize("as_json", [False, True])
def test_echo_prints_live_poses(capsys, tmp_path, as_json):
    from service.commands import echo

    port, stop = free_port(), threading.Event()
    t = threading.Thread(target=_publish, args=(port, "echo1", 0, stop), daemon=True)
    t.start()
    out = tmp_path / "poses.jsonl"
    argv = ["--connect", f"tcp/127.0.0.1:{port}", "--studio", "echo1", "--count", "6", "--out", str(out)]
    try:
        rc = echo.run(_args(echo, argv + (["--json"] if as_json else [])))
    finally:
        stop.set()
        t.join(5)
    assert rc == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 6 and len(out.read_text().splitlines()) == 6
    if as_json:
        recs = [json.loads(line) for line in lines]
        assert all(r["cameras"] == 4 for r in recs)
        assert [r["frame"] for r in recs] == sorted(r["frame"] for r in recs)
    else:
        assert any("LOST" in line and "reason: lost: test" in line for line in lines)
        assert any("pelvis (+0.100 +0.200 +0.900) m" in line and "lat 12.5 ms" in line for line in lines)


def test_echo_without_peer_is_a_clear_error(capsys):
    from service.commands import echo

    rc = echo.run(_args(echo, ["--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout-s", "0.3"]))
    assert rc == 2 and "no zenoh peer or router reachable" in capsys.readouterr().err


def test_export_command_writes_bvh(tmp_path, rng, capsys):
    model_mod = pytest.importorskip("tracker.body.model")
    from service.commands import export
    from service.export import write_pose_records

    model = model_mod.load_model("knossow40")
    recs = [PoseRecord.from_dict({"frame": k, "timestamp_ns": k * 10_000_000, "ok": True, "model": model.name,
                                  "params": model.random_params(rng, fraction=0.3).tolist()}) for k in range(4)]
    write_pose_records(tmp_path / "p.jsonl", recs)
    rc = export.run(_args(export, [str(tmp_path / "p.jsonl"), "--bvh", str(tmp_path / "o.bvh")]))
    assert rc == 0 and "4 frames at 100.00 fps" in capsys.readouterr().out
    rc = export.run(_args(export, [str(tmp_path / "p.jsonl"), "--bvh", str(tmp_path / "o.bvh"), "--model", "nope"]))
    assert rc == 2 and "--model" in capsys.readouterr().err


def test_echo_bad_out_file_is_a_clear_error_before_connecting(capsys, tmp_path):
    from service.commands import echo

    port = free_port()
    peer = open_session(ZenohSettings.loopback(port, listen=True))  # reachable: only --out is wrong
    try:
        rc = echo.run(_args(echo, ["--connect", f"tcp/127.0.0.1:{port}", "--timeout-s", "2",
                                   "--out", str(tmp_path / "no" / "such" / "p.jsonl")]))
    finally:
        peer.close()
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("contourcap echo: --out:") and "p.jsonl" in err


def test_view_bad_save_path_is_a_clear_error(capsys, tmp_path):
    pytest.importorskip("rerun")
    from service.commands import view

    port = free_port()
    peer = open_session(ZenohSettings.loopback(port, listen=True))
    try:
        rc = view.run(_args(view, ["--connect", f"tcp/127.0.0.1:{port}", "--timeout-s", "2",
                                   "--save", str(tmp_path / "no" / "x.rrd")]))
    finally:
        peer.close()
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("contourcap view: --save") and "x.rrd" in err
