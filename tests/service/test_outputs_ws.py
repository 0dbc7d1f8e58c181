"""`contourcap stream ws --replay`: a WebSocket client receives every record in order, equal to the file's;
a slow client has its oldest queued records dropped (bounded memory); the page at / draws the skeleton
in headless Chromium (Debian's `chromium`; skipped where it is not installed)."""

from __future__ import annotations

import asyncio
import json
import os
import re
import shutil
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

websockets = pytest.importorskip("websockets", minversion="13")
pytest.importorskip("tracker.synthetic.retarget")

from tests.support.outputs import make_take  # noqa: E402
from service.export import write_pose_records  # noqa: E402
from service.outputs.ws import PoseHub  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    records, _ = make_take()
    path = tmp_path_factory.mktemp("take") / "poses.jsonl"
    write_pose_records(path, records)
    return path, records


def _start_server(path, *extra):
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-m", "service.cli", "stream", "ws", "--replay", str(path),
                             "--port", "0", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, cwd=REPO)
    line = proc.stdout.readline()
    m = re.search(r"ws://127\.0\.0\.1:(\d+)/", line)
    if not m:
        proc.kill()
        raise AssertionError(f"no server address in {line!r}: {proc.stderr.read()}")
    return proc, int(m.group(1))


def test_ws_client_receives_every_record_in_order(take):
    path, records = take
    proc, port = _start_server(path, "--rate", "2")
    try:
        async def receive():
            got = []
            async with websockets.connect(f"ws://127.0.0.1:{port}/") as ws:
                async for msg in ws:
                    got.append(msg)
            return got

        got = asyncio.run(asyncio.wait_for(receive(), 60))
        out, err = proc.communicate(timeout=20)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert [json.loads(m) for m in got] == [json.loads(line) for line in path.read_text().splitlines()]
    assert f"sent {len(records)} poses" in out and "0 dropped" in out


def test_slow_client_drops_oldest_and_memory_stays_bounded():
    async def scenario():
        hub = PoseHub(queue_size=4)
        sent = []

        class SlowWs:  # a client that never gets to send: its queue must stay at 4
            async def send(self, text):
                sent.append(text)
                await asyncio.sleep(3600)

            async def close(self, *a):
                pass

        task = asyncio.create_task(hub.handler(SlowWs()))
        await asyncio.sleep(0)
        for k in range(100):
            hub.publish(str(k))
            await asyncio.sleep(0)
        client = next(iter(hub.clients))
        queued = [client.queue.get_nowait() for _ in range(client.queue.qsize())]
        task.cancel()
        return sent, queued, hub.dropped

    sent, queued, dropped = asyncio.run(scenario())
    assert sent == ["0"] and queued == ["96", "97", "98", "99"]  # the newest kept
    assert dropped == 100 - 1 - 4


def test_page_is_served_and_unknown_paths_404(take):
    path, _ = take
    proc, port = _start_server(path)
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as r:
            body = r.read().decode()
            assert r.headers["Content-Type"].startswith("text/html")
        assert "<canvas" in body and "new WebSocket" in body
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/nope", timeout=5)
        assert exc.value.code == 404
        exc.value.close()
    finally:
        proc.terminate()
        proc.wait(20)


def _chromium():
    for name in ("chromium", "chromium-browser", "google-chrome"):
        exe = shutil.which(name)
        if exe:
            return exe
    return None


@pytest.mark.skipif(_chromium() is None, reason="headless Chromium not installed (Debian: apt-get install chromium)")
def test_page_draws_the_moving_skeleton_in_headless_chromium(take, tmp_path):
    path, records = take
    proc, port = _start_server(path, "--rate", "2")
    profile = tmp_path / "profile"
    browser = subprocess.Popen([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                "--remote-debugging-port=0", f"--user-data-dir={profile}", "--window-size=800,600",
                                f"http://127.0.0.1:{port}/"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 30
        while not (profile / "DevToolsActivePort").exists():
            assert time.monotonic() < deadline, "chromium did not start"
            time.sleep(0.1)
        time.sleep(0.2)
        devport = int((profile / "DevToolsActivePort").read_text().split()[0])
        state, png = _watch_page(devport, len(records), deadline=time.monotonic() + 60)
    finally:
        browser.terminate()
        proc.terminate()
        browser.wait(10)
        proc.wait(10)
    (tmp_path / "page.png").write_bytes(png)
    assert state["received"] == len(records) and state["lastFrame"] == records[-1].frame
    assert state["drawn"] >= 10 and state["movedPx"] > 20  # the skeleton was drawn and it moved on screen
    assert state["frameText"] == f"frame {records[-1].frame}" and state["status"] in ("ok", "stream ended")
    assert len(png) > 10_000


def _watch_page(devport: int, n_records: int, deadline: float):
    """Poll window.contourcap over the DevTools protocol until every record arrived; then a screenshot."""
    import base64

    from websockets.sync.client import connect

    with urllib.request.urlopen(f"http://127.0.0.1:{devport}/json", timeout=5) as r:
        pages = [t for t in json.load(r) if t.get("type") == "page"]
    ident = iter(range(1, 10**6))
    expr = ("JSON.stringify(Object.assign({}, window.contourcap || {}, {first: null, last: null, "
            "frameText: document.getElementById('frame') && document.getElementById('frame').textContent, "
            "status: document.getElementById('status') && document.getElementById('status').textContent}))")
    with connect(pages[0]["webSocketDebuggerUrl"], max_size=2**26) as cdp:
        def call(method, **params):
            i = next(ident)
            cdp.send(json.dumps({"id": i, "method": method, "params": params}))
            while True:
                msg = json.loads(cdp.recv(timeout=10))
                if msg.get("id") == i:
                    return msg["result"]

        state = {}
        while time.monotonic() < deadline:
            res = call("Runtime.evaluate", expression=expr, returnByValue=True)
            state = json.loads(res["result"].get("value") or "{}")
            if state.get("received") == n_records and state.get("drawn", 0) > 0:
                break
            time.sleep(0.2)
        time.sleep(0.3)
        png = base64.b64decode(call("Page.captureScreenshot", format="png")["data"])
    return state, png
