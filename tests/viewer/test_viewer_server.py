"""The visualizer's server without a browser: wire format, flow control, commands, assets."""
from __future__ import annotations

import asyncio
import json
import re
import socket
import time
import urllib.error
import urllib.request

import numpy as np
import pytest
from viewer_support import TESTING, BusTap, free_port, run_async, viewer_stats, viewer_url, wait_until, ws_url

from mocapgraph.messages import ActorPose, Diagnostics, Envelope, MarkerFrame, NodeStatus
from mocapgraph.viewer.wire import BundleError, build_bundle, decode_bundle, encode_record

websockets_client = pytest.importorskip("websockets.asyncio.client")


def _env(type_name: str, seq: int = 7) -> Envelope:
    return Envelope("t", type_name, 1, seq, 1_700_000_000_123_456_789, 1_700_000_000_223_456_789, "node", False)


def test_bundle_round_trip_keeps_nan_and_alignment():
    pos = np.array([[0.1, 0.2, 0.3], [np.nan, np.nan, np.nan], [1.5, -2.25, 0.0]])
    frame = MarkerFrame(frame_number=41, rate_hz=240.0, positions=pos, valid=[True, False, True],
                        residual=np.array([0.001, np.nan, 0.002], np.float32))
    pose = ActorPose(actor="alice", frame_number=3, joint_positions=np.ones((2, 3)), joint_quality=[2, 0],
                     limb_orientations=np.tile([1.0, 0, 0, 0], (1, 1)), limb_quality=[1], limb_visible_markers=[4])
    diag = Diagnostics(node="viz", edge_topics=["markers"], edge_senders=["a"], edge_rate_hz=[240.0],
                       edge_latency_ms=[np.nan], edge_latency_max_ms=[1.0], edge_received=[2**40], edge_gaps=[3],
                       edge_rejected=[0], output_topics=[], output_sent=np.zeros(0, np.int64))
    status = NodeStatus(node="calib", state="idle", progress=float("nan"))
    recs = [encode_record("markers", "k1", _env("MarkerFrame"), frame),
            encode_record("actor_pose", "k2", _env("ActorPose"), pose),
            encode_record("diagnostics", "k3", _env("Diagnostics"), diag),
            encode_record("calibration_status", "k4", _env("NodeStatus"), status)]
    data = build_bundle(recs, 12.5)
    t_ms, out = decode_bundle(data)
    assert t_ms == 12.5 and [r["key"] for r in out] == ["k1", "k2", "k3", "k4"]
    m = out[0]
    assert m["fields"]["frame_number"] == 41 and m["seq"] == 7 and m["sender"] == "node"
    np.testing.assert_array_equal(m["arrays"]["positions"], pos.astype(np.float32))  # NaN where NaN
    assert m["arrays"]["positions"].dtype == np.float32 and m["arrays"]["valid"].tolist() == [1, 0, 1]
    assert out[1]["arrays"]["joint_quality"].dtype == np.int8
    assert out[2]["arrays"]["edge_received"][0] == 2**40  # int64 counters exact as float64
    assert out[2]["fields"]["edge_topics"] == ["markers"]
    assert out[3]["fields"]["progress"] is None  # JSON has no NaN
    assert abs(m["publish_ms"] - 1_700_000_000_223.456789) < 1e-3
    n = int.from_bytes(data[4:8], "little")
    base = 8 + n + (-(8 + n)) % 8
    assert base % 8 == 0
    assert all(off % 8 == 0 for r in json.loads(data[8:8 + n])["records"] for _, _, off in r["arrays"].values())
    with pytest.raises(BundleError):
        decode_bundle(b"XXXX" + data[4:])
    with pytest.raises(BundleError):
        decode_bundle(data[:-8])


def _graph(port: int, rate: float = 240.0) -> str:
    return f"""
nodes:
  - name: alice
    type: {TESTING}:StagePerformer
    params: {{actor: alice, rate_hz: {rate}, publish: [markers, actor]}}
  - name: calib
    type: {TESTING}:CommandEcho
  - name: viz
    type: visualizer
    params: {{port: {port}, window: 2, max_rate_hz: 50.0}}
"""


async def _collect(ws, out: list, times: list, ack: bool, stop=lambda: False) -> None:
    """Receive bundles into ``out`` (arrival times in ``times``) until ``stop()`` or cancelled."""
    while not stop():
        msg = await ws.recv()
        if isinstance(msg, bytes):
            out.append(decode_bundle(msg)[1])
            times.append(time.monotonic())
            if ack:
                await ws.send("a")


@pytest.mark.timing
def test_a_browser_that_does_not_ack_gets_no_backlog(launch_graph):
    port = free_port()
    g = launch_graph(_graph(port))
    g.wait_ready()
    url = viewer_url(g)

    async def run():
        async with websockets_client.connect(ws_url(url)) as slow, \
                websockets_client.connect(ws_url(url)) as fast:
            hello = json.loads(await slow.recv())
            json.loads(await fast.recv())
            assert hello["type"] == "hello" and hello["node"] == "viz"
            assert hello["topics"]["markers"] == {"topic": "markers", "type": "MarkerFrame", "latched": False}
            puts0 = viewer_stats(url)["store_puts"]
            slow_bundles: list = []
            slow_task = asyncio.create_task(_collect(slow, slow_bundles, [], ack=False))
            # The acking one runs until it has seen 60 bundles: an event, with a deadline only
            # against a hang (60 bundles take 1.2 s at 50/s; 4 busy loops on 2 cores ~3 s).
            fast_bundles: list = []
            fast_times: list = []
            t0 = time.monotonic()
            await asyncio.wait_for(_collect(fast, fast_bundles, fast_times, ack=True,
                                            stop=lambda: len(fast_bundles) >= 60), 30)
            elapsed = time.monotonic() - t0
            puts = viewer_stats(url)["store_puts"] - puts0
            # Baseline of this machine, now: the longest wait between two bundles the acking
            # client saw. A bundle the slow one could still get would have come within it.
            quiet = max(0.2, 3 * float(np.max(np.diff(fast_times))))
            await asyncio.sleep(quiet)
            slow_task.cancel()
            await asyncio.gather(slow_task, return_exceptions=True)
            # The slow one holds the window (2) and no more, while the bus kept flowing at 240 Hz.
            assert len(slow_bundles) == 2
            assert puts > 2 * len(fast_bundles)  # several frames per bundle: the store coalesced them
            # The acking one is paced by max_rate_hz (50): never more than 50/s (+ the window).
            assert len(fast_bundles) <= 50 * elapsed + 2, (len(fast_bundles), elapsed)
            for recs in fast_bundles:
                keys = [r["key"] for r in recs]
                assert len(keys) == len(set(keys))
            frames = [r["fields"]["frame_number"] for recs in fast_bundles for r in recs if r["topic"] == "markers"]
            assert len(frames) >= 55 and frames == sorted(frames)
            # The newest frame each time, never a backlog: frames are skipped between bundles
            # (240 Hz against <= 50 bundles/s: ~4.8 frames per bundle when the publisher keeps up).
            assert frames[-1] - frames[0] > 1.5 * len(frames), (frames[0], frames[-1], len(frames))
            # One ack lets exactly one more bundle through, with the newest frame.
            await slow.send("a")
            more: list = []
            more_task = asyncio.create_task(_collect(slow, more, [], ack=False))
            await asyncio.wait_for(_until(lambda: more), 10)
            await asyncio.sleep(quiet)
            more_task.cancel()
            await asyncio.gather(more_task, return_exceptions=True)
            assert len(more) == 1
            newest = [r for r in more[0] if r["topic"] == "markers"][0]["fields"]["frame_number"]
            assert newest > frames[-1]

    run_async(run)


async def _until(cond) -> None:
    while not cond():
        await asyncio.sleep(0.005)


@pytest.mark.timing
def test_commands_are_checked_and_published(launch_graph):
    port = free_port()
    g = launch_graph(_graph(port, rate=60.0))
    g.wait_ready()
    url = viewer_url(g)
    tap = BusTap(g.master, ["calibration_command", "calibration_status"])

    async def run():
        async with websockets_client.connect(ws_url(url)) as ws:
            await ws.recv()
            replies = {}
            for i, req in enumerate([
                {"type": "command", "channel": "calibration", "command": "explode"},
                {"type": "command", "channel": "kettle", "command": "play"},
                {"type": "command", "channel": "calibration", "command": "process", "args": [1]},
                {"type": "command", "channel": "calibration", "command": "find_base_pose", "target": "calib"},
            ]):
                await ws.send(json.dumps({**req, "id": i}))
            while len(replies) < 4:
                msg = await ws.recv()
                if isinstance(msg, str):
                    r = json.loads(msg)
                    replies[r["id"]] = r
                else:
                    await ws.send("a")
            return replies

    try:
        wait_until(lambda: tap.of("calibration_status"), what="calibration status on the bus")
        replies = run_async(run)
        assert "no command 'explode'" in replies[0]["error"] and not replies[0]["ok"]
        assert "unknown channel" in replies[1]["error"]
        assert "args must be an object" in replies[2]["error"]
        assert replies[3]["ok"]
        wait_until(lambda: tap.of("calibration_status")[-1][1].state == "base_pose_found", what="base pose found")
        sent = [m for _, m in tap.of("calibration_command")]
        assert [(m.target, m.command, json.loads(m.args_json)) for m in sent] == [("calib", "find_base_pose", {})]
    finally:
        tap.close()

    # The page is self-contained: every file it loads is served here, nothing from elsewhere.
    def get(path: str) -> tuple[int, str, str]:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
                return r.status, r.headers["Content-Type"], r.read().decode()
        except urllib.error.HTTPError as exc:
            return exc.code, "", ""

    status, ctype, html = get("/")
    assert status == 200 and ctype.startswith("text/html")
    refs = re.findall(r'(?:src|href)="([^"]+)"', html)
    imports = json.loads(re.search(r'<script type="importmap">(.*?)</script>', html, re.S).group(1))["imports"]
    modules = ["js/boot.js", "js/main.js"]
    seen, bare = set(), set()
    while modules:
        path = modules.pop()
        if path in seen:
            continue
        seen.add(path)
        status, ctype, text = get("/" + path)
        assert status == 200 and ctype.startswith("text/javascript"), path
        assert not re.search(r"https?://|//cdn", text), path
        modules += ["js/" + m for m in re.findall(r'from "\./([\w.]+)"', text)]
        bare |= set(re.findall(r'from "(three[\w./]*)"', text))
    assert seen >= {"js/main.js", "js/stage.js", "js/avatar.js", "js/net.js", "js/scene.js", "js/panel.js",
                    "js/camera.js", "js/video.js"}
    # three.js and the add-ons the page imports resolve (import map) to files this server serves,
    # and the modules they import in turn too; nothing else under node_modules is served
    assert bare == {"three", "three/addons/controls/OrbitControls.js", "three/addons/loaders/GLTFLoader.js"}
    three = [imports["three"] if b == "three" else imports["three/addons/"] + b[len("three/addons/"):] for b in bare]
    three += ["./three/build/three.core.js", "./three/examples/jsm/utils/BufferGeometryUtils.js",
              "./three/examples/jsm/utils/SkeletonUtils.js"]
    for path in three:
        status, ctype, text = get(path[1:])
        assert status == 200 and ctype.startswith("text/javascript") and len(text) > 1000, path
    for path in ("/three/package.json", "/three/build/../package.json", "/three/src/Three.js", "/three/%2e%2e/three/package.json",
                 "/three/examples/jsm/loaders/FBXLoader.js", "/node_modules/three/build/three.module.js"):
        assert get(path)[0] == 404, path
    for ref in refs:
        assert not ref.startswith(("http", "//")), ref
        if not ref.startswith("data:"):
            assert get("/" + ref)[0] == 200, ref
    assert get("/../pyproject.toml")[0] == 404
    assert get("/nothing.js")[0] == 404


def test_a_taken_port_is_a_one_line_error(launch_graph):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        g = launch_graph(_graph(port, rate=30.0))
        line = g.wait_for("cannot serve the viewer", timeout=20)
        assert f"127.0.0.1:{port}" in line and "in use" in line
        assert g.proc.wait(20) != 0
    assert "Traceback" not in g.output


@pytest.mark.parametrize("name", ["viewer_stage.yaml", "viewer_test_pattern.yaml"])
def test_example_graphs_pass_the_graph_check(name):
    from pathlib import Path

    from mocapgraph.launch.check import check_graph
    from mocapgraph.launch.graph import load_graph

    graph = check_graph(load_graph(Path(__file__).resolve().parents[2] / "graph_configs" / "examples" / name))
    assert "viewer" in [n.name for n in graph.nodes]
