"""Nested or huge JSON from outside is refused in one line, never a crash (issue 30, item 5).

Real nodes get NodeCommands whose ``args_json`` is 50 000 ``[`` (what took the bag player, the
physics tracker and the calibration node down with RecursionError) from an ``external:``
publisher this test binds; the viewer's WebSocket and the Foxglove bridge get the same nesting
from a real WebSocket client, and the bridge a Host header of ``[``. Each answers with one line,
keeps running and still obeys a good command or client afterwards.
"""
from __future__ import annotations

import asyncio
import http.client
import json
import re
import sys
import time
from pathlib import Path

import pytest
import zmq

from graph_helpers import read_jsonl, wait_until
from mocapgraph.messages import NodeCommand, encode
from mocapgraph.messages.codec import topic_frame

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "viewer"))
from viewer_support import free_port, viewer_url, ws_url  # noqa: E402

websockets = pytest.importorskip("websockets.asyncio.client")

NESTED = "[" * 50_000
DEEP_OBJECT = '{"a":' * 10_000 + "1" + "}" * 10_000   # 60 kB: under the size limit, refused for depth
HUGE = json.dumps({"path": "x" * (2 << 20)})
TOPICS = ("calibration_command", "player_command", "physics_command")


class Commands:
    """One XPUB publishing NodeCommands on TOPICS (the graph declares it under ``external:``)."""

    def __init__(self) -> None:
        self.sock = zmq.Context.instance().socket(zmq.XPUB)
        self.port = self.sock.bind_to_random_port("tcp://127.0.0.1")
        self.seq = 0

    @property
    def external(self) -> str:
        ep = f"tcp://127.0.0.1:{self.port}"
        return "external:\n" + "".join(f"  - {{topic: {t}, type: NodeCommand, endpoint: \"{ep}\"}}\n" for t in TOPICS)

    def wait_subscribers(self) -> None:
        seen: set[bytes] = set()
        t_end = time.monotonic() + 90
        while len(seen) < len(TOPICS) and time.monotonic() < t_end:
            if self.sock.poll(1000):
                seen.add(self.sock.recv())
        assert seen >= {b"\x01" + topic_frame(t) for t in TOPICS}, seen

    def send(self, topic: str, command: str, args_json: str) -> None:
        self.seq += 1
        msg = NodeCommand(target="", command=command, args_json=args_json)
        self.sock.send_multipart([bytes(f) for f in encode(topic, msg, self.seq, time.time_ns(), "probe")])


def _small_bag(path: Path) -> None:
    import numpy as np

    from mocapgraph.bag.writer import BagWriter
    from mocapgraph.messages import MarkerFrame

    with BagWriter(str(path)) as w:
        for i in range(240):
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=120.0, positions=np.zeros((4, 3)),
                                           valid=np.ones(4, bool), residual=np.zeros(4, np.float32)),
                    seq=i + 1, capture_ns=int(i * 1e9 / 120))


def _last(log: Path, topic: str, node: str) -> dict:
    recs = [r["msg"] for r in read_jsonl(log, topic) if r["msg"].get("node") == node]
    return recs[-1] if recs else {}


@pytest.fixture(scope="module")
def graphs(launch_module_graph, tmp_path_factory) -> dict:
    """The two graphs of this module (neither judged on time), launched together: each spends
    seconds starting up, and each test stops its own."""
    tmp = tmp_path_factory.mktemp("nested")
    bag = tmp / "b.mcap"
    _small_bag(bag)
    log = tmp / "log.jsonl"
    cmd = Commands()
    commandable = launch_module_graph(cmd.external + f"""\
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 30.0, loop: true}}
  - name: cal
    type: calibration
  - name: player
    type: bag_player
    params: {{file: "{bag}", loop: true}}
  - name: src
    type: synthetic_character
    params: {{rate_hz: 60.0}}
  - name: tracker
    type: physics_tracker
    params: {{stage: balls}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [calibration_status, player_status, physics_state]}}
""")
    servers = launch_module_graph(f"""\
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 60.0, n_markers: 4}}
  - name: viz
    type: visualizer
    params: {{port: {free_port()}}}
  - name: fox
    type: foxglove_bridge
    params: {{port: 0, token: s3cret}}
""")
    return {"commandable": (commandable, cmd, log), "servers": servers}


def test_nested_args_json_is_refused_by_every_commandable_node(graphs):
    g, cmd, log = graphs["commandable"]
    g.wait_ready(timeout=120)
    cmd.wait_subscribers()
    wait_until(lambda: read_jsonl(log, "physics_state"), timeout=60, what="the physics world", graph=g)
    for bad in (NESTED, DEEP_OBJECT, HUGE):
        cmd.send("calibration_command", "reset", bad)
        cmd.send("player_command", "seek", bad)
        cmd.send("physics_command", "push", bad)
    # each node says why, in one line, and obeys the next good command
    cmd.send("calibration_command", "find_base_pose", "{}")
    cmd.send("player_command", "pause", "{}")
    wait_until(lambda: _last(log, "calibration_status", "cal").get("state") == "finding_base_pose"
               or _last(log, "calibration_status", "cal").get("state") == "base_pose_found",
               timeout=30, what="the calibration node obeying find_base_pose", graph=g)
    wait_until(lambda: _last(log, "player_status", "player").get("state") == "paused", timeout=30,
               what="the player obeying pause", graph=g)
    n_states = len(read_jsonl(log, "physics_state"))
    wait_until(lambda: len(read_jsonl(log, "physics_state")) > n_states + 30, timeout=30,
               what="the tracker going on", graph=g)
    out = g.output
    for node in ("cal", "player", "tracker"):
        lines = [ln for ln in g.lines if ln.startswith(f"[{node}]") and "over the limit" in ln]
        assert len(lines) == 3, (node, out[-3000:])
        assert all(len(ln) < 400 for ln in lines), lines
    assert "nested 50000 deep" in out and "nested 10000 deep" in out and "bytes is over the limit" in out
    assert "RecursionError" not in out and "Traceback" not in out and "exited" not in out, out[-3000:]
    assert g.stop() == 0


async def _viewer_session(url: str) -> list[dict]:
    replies = []
    async with websockets.connect(ws_url(url), max_size=None) as ws:
        await ws.recv()  # hello
        for i, text in enumerate((NESTED, DEEP_OBJECT, json.dumps({"type": "command", "id": 9, "channel": "player",
                                                                  "command": "play", "args": json.loads("[" * 30 + "]" * 30)}))):
            await ws.send(text)
            while True:
                m = await asyncio.wait_for(ws.recv(), 10)
                if isinstance(m, str):
                    replies.append(json.loads(m))
                    break
                await ws.send("a")
    return replies


async def _foxglove_session(url: str) -> tuple[list[dict], int]:
    async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"], max_size=None) as ws:
        channels: dict[str, dict] = {}
        while "/markers" not in channels:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        await ws.send(NESTED)
        await ws.send('{"op": "subscribe", "subscriptions": ' + "[" * 5000 + "]" * 5000 + "}")
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/markers"]["id"]}]}))
        statuses, data = [], 0
        while data < 5:
            m = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(m, bytes):
                data += 1
            elif json.loads(m)["op"] == "status":
                statuses.append(json.loads(m))
        return statuses, data


def _raw_host(port: int, host: str) -> int:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.putrequest("GET", "/", skip_host=True)
    conn.putheader("Host", host)
    for k, v in (("Upgrade", "websocket"), ("Connection", "Upgrade"), ("Sec-WebSocket-Version", "13"),
                 ("Sec-WebSocket-Key", "dGhlIHNhbXBsZSBub25jZQ=="), ("Sec-WebSocket-Protocol", "foxglove.websocket.v1")):
        conn.putheader(k, v)
    conn.endheaders()
    status = conn.getresponse().status
    conn.close()
    return status


def test_viewer_and_foxglove_bridge_refuse_nested_json_and_a_host_of_a_bracket(graphs):
    g = graphs["servers"]
    g.wait_ready()
    replies = asyncio.run(_viewer_session(viewer_url(g)))
    assert [r["ok"] for r in replies] == [False, False, False], replies
    assert "nested 50000 deep" in replies[0]["error"] and "nested 10000 deep" in replies[1]["error"]
    assert "nested 31 deep" in replies[2]["error"], replies[2]
    fox_url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    fox_port = int(re.search(r":(\d+)/", fox_url).group(1))
    for host in ("[", "[::1", "]["):
        assert _raw_host(fox_port, host) == 400
    statuses, data = asyncio.run(_foxglove_session(fox_url))
    text = " | ".join(s["message"] for s in statuses)
    assert "nested 50000 deep" in text and "nested 5001 deep" in text, text
    assert data == 5
    assert g.proc.poll() is None
    assert g.stop() == 0
    assert "Traceback" not in g.output and "RecursionError" not in g.output, g.output[-3000:]
