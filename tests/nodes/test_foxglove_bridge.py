"""The foxglove_bridge node in a real graph, seen by a Foxglove WebSocket client written from the
protocol's documentation: advertised channels with their schemas, a subscribed scene decoded with
the advertised schema (the right markers, where the pattern put them), JSON diagnostics; the
token, Origin and Host checks refuse strangers, on every port the bridge process listens on."""
from __future__ import annotations

import asyncio
import base64
import json
import re
import struct

import numpy as np
import pytest
import websockets
from websockets.exceptions import InvalidStatus

from foxglove_decode import message_class
from graph_helpers import node_pids
from eco_support import STAGE_PERFORMER, pattern_positions

N, RATE, TOKEN = 10, 120.0, "s3cret-token"
GRAPH = f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: {RATE}, n_markers: {N}, missing_every: 5}}
  - name: performer
    type: {STAGE_PERFORMER}
    params: {{actor: ann, rate_hz: 30.0, publish: [actor]}}
  - name: fox
    type: foxglove_bridge
    params: {{port: 0, token: {TOKEN}}}
"""


async def _session(url: str, frames: dict[str, int]):
    """Connect as Foxglove does, collect advertisements, subscribe to the topics of ``frames`` and
    collect that many messages of each."""
    want = set(frames)
    async with websockets.connect(url, subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"],
                                  max_size=None) as ws:
        info = json.loads(await asyncio.wait_for(ws.recv(), 10))
        assert info["op"] == "serverInfo"
        channels: dict[str, dict] = {}
        while not want <= set(channels):
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        subs = {i + 1: channels[t] for i, t in enumerate(sorted(want))}
        await ws.send(json.dumps({"op": "subscribe",
                                  "subscriptions": [{"id": i, "channelId": c["id"]} for i, c in subs.items()]}))
        got: dict[str, list] = {t: [] for t in want}
        while any(len(got[t]) < n for t, n in frames.items()):
            m = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(m, str):
                continue  # further advertisements, status
            assert m[0] == 0x01  # MessageData: opcode, subscription id, timestamp ns, payload
            sub, stamp = struct.unpack_from("<IQ", m, 1)
            got[subs[sub]["topic"]].append((stamp, m[13:]))
        return info, channels, got


@pytest.fixture(scope="module")
def graphs(launch_module_graph) -> dict:
    """GRAPH three times, launched together (each spends seconds starting up): "shared" for the
    tests that only read from it (connect, subscribe, inspect ports), and one for each test that
    counts refusals in the log or stops the graph ("strangers", "bad_client")."""
    return {name: launch_module_graph(GRAPH) for name in ("shared", "strangers", "bad_client")}


@pytest.fixture(scope="module")
def bridge(graphs):
    g = graphs["shared"]
    g.wait_ready()
    return g


def test_foxglove_client_decodes_the_scene(bridge):
    g = bridge
    line = g.wait_for("foxglove bridge at ")
    url = re.search(r"(ws://\S+)", line).group(1)
    assert url.startswith("ws://127.0.0.1:") and url.endswith(f"?token={TOKEN}")
    info, channels, got = asyncio.run(_session(url, {"/markers": 60, "/actor_pose": 5, "/diagnostics/pattern": 1}))
    assert "mocapgraph fox" in info["name"]
    scene = channels["/markers"]
    assert (scene["encoding"], scene["schemaName"], scene["schemaEncoding"]) == \
        ("protobuf", "foxglove.SceneUpdate", "protobuf")
    SceneUpdate = message_class("foxglove.SceneUpdate", base64.b64decode(scene["schema"]))
    counts = set()
    for stamp, data in got["/markers"]:
        (ent,) = SceneUpdate.FromString(data).entities
        frame = int(dict((kv.key, kv.value) for kv in ent.metadata)["frame"])
        expect = pattern_positions(frame, N, RATE)
        if frame % 5 == 0:
            expect = expect[1:]  # marker 0 missing on every 5th frame: not drawn
        pos = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in ent.spheres])
        np.testing.assert_array_equal(pos, expect)
        assert ent.timestamp.seconds * 10**9 + ent.timestamp.nanos == stamp
        counts.add(len(ent.spheres))
    assert counts == {N, N - 1}
    actor = SceneUpdate.FromString(got["/actor_pose"][-1][1]).entities[0]
    assert actor.id == "actor_pose/ann" and len(actor.spheres) == 16 and len(actor.lines[0].points) == 30
    diag = channels["/diagnostics/pattern"]
    assert diag["encoding"] == "json" and diag["schemaEncoding"] == "jsonschema"
    rec = json.loads(got["/diagnostics/pattern"][-1][1])
    assert rec["node"] == "pattern" and rec["sent"]["markers"] > 0


async def _refused(url: str, headers: dict | None = None, **kw) -> int:
    try:
        async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"], additional_headers=headers,
                                      open_timeout=10, **kw):
            return 101
    except InvalidStatus as exc:
        return exc.response.status_code


def test_strangers_are_refused(graphs):
    g = graphs["strangers"]
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    bare = url.split("?")[0]
    assert asyncio.run(_refused(bare)) == 403
    assert asyncio.run(_refused(bare + "?token=guess")) == 403
    assert asyncio.run(_refused(url, {"Origin": "https://evil.example"})) == 403
    assert asyncio.run(_refused(url, {"Origin": "https://app.foxglove.dev"})) == 101
    port = bare.rsplit(":", 1)[1].rstrip("/")
    assert asyncio.run(_refused(url.replace("127.0.0.1", "localhost"))) == 101
    # DNS rebinding: a page of evil.example resolved to 127.0.0.1 sends Host: evil.example
    assert asyncio.run(_refused(url.replace("127.0.0.1", "evil.example"), host="127.0.0.1", port=int(port))) == 403
    g.stop()
    assert "refused" in g.output and "'token': 2" in g.output


def listening_tcp_ports(pid: int) -> set[int]:
    """TCP ports ``pid`` listens on: its socket inodes (/proc/pid/fd) matched in /proc/pid/net/tcp{,6}."""
    import os

    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    ports = set()
    for table in ("tcp", "tcp6"):
        with open(f"/proc/{pid}/net/{table}") as f:
            for row in f.readlines()[1:]:
                cols = row.split()
                if cols[3] == "0A" and cols[9] in inodes:  # 0A: LISTEN
                    ports.add(int(cols[1].rsplit(":", 1)[1], 16))
    return ports


async def _handshake(port: int, query: str = "") -> str:
    """What a Foxglove client without our token gets from ``port``: 'open', 'http <status>' or 'no websocket'."""
    try:
        async with websockets.connect(f"ws://127.0.0.1:{port}/{query}", subprotocols=["foxglove.websocket.v1",
                                                                                      "foxglove.sdk.v1"],
                                      open_timeout=5):
            return "open"
    except InvalidStatus as exc:
        return f"http {exc.response.status_code}"
    except (OSError, asyncio.TimeoutError, websockets.exceptions.InvalidHandshake,
            websockets.exceptions.ConnectionClosed, EOFError):
        return "no websocket"


def test_no_port_of_the_bridge_process_opens_without_the_token(bridge):
    """The SDK's own server (no authentication) used to listen on a second loopback port; now
    every listening port of the process either refuses a tokenless client with 403 or is no
    WebSocket server at all (the bus's ZeroMQ sockets), and exactly one port speaks HTTP."""
    g = bridge
    assert g.proc.poll() is None, g.output
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    gate = int(url.split("?")[0].rsplit(":", 1)[1].rstrip("/"))
    pid = node_pids(g)["fox"]
    ports = listening_tcp_ports(pid)
    assert gate in ports
    answers = {p: asyncio.run(_handshake(p)) for p in sorted(ports)}
    assert answers[gate] == "http 403"
    assert {p for p, a in answers.items() if a != "no websocket"} == {gate}, answers
    assert "open" not in {asyncio.run(_handshake(p, "?token=guess")) for p in ports}
    # the one port, with the token, serves the protocol (scene decoding: the test above)
    info, channels, got = asyncio.run(_session(url, {"/markers": 3}))
    assert info["op"] == "serverInfo" and channels["/markers"]["schemaName"] == "foxglove.SceneUpdate"


async def _bad_client(url: str) -> tuple[list[dict], int]:
    """Sends what the server does not support or cannot parse; returns the status replies and how
    many marker messages arrived afterwards on a valid subscription."""
    async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"], max_size=None) as ws:
        channels: dict[str, dict] = {}
        while "/markers" not in channels:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        marker_id = channels["/markers"]["id"]
        for bad in ("{not json", json.dumps({"op": "getParameters", "parameterNames": []}),
                    json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": 99999}]}),
                    json.dumps({"op": "subscribe", "subscriptions": "all"}),
                    json.dumps({"op": "unsubscribe", "subscriptionIds": [42]}), b"\x01\x00\x00\x00\x00"):
            await ws.send(bad)
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": marker_id}]}))
        statuses, data = [], 0
        while data < 5:
            m = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(m, bytes):
                assert struct.unpack_from("<BI", m)[:2] == (1, 7)
                data += 1
            elif json.loads(m)["op"] == "status":
                statuses.append(json.loads(m))
        return statuses, data


def test_unsupported_or_malformed_client_messages_get_a_status_and_the_session_goes_on(graphs):
    g = graphs["bad_client"]
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    statuses, data = asyncio.run(_bad_client(url))
    assert [s["level"] for s in statuses] == [2, 2, 2, 2, 1, 2]
    text = " | ".join(s["message"] for s in statuses)
    for part in ("not JSON", "unsupported op 'getParameters'", "no channel 99999", "must be a list",
                 "no subscription 42", "binary client messages"):
        assert part in text
    assert data == 5
    g.stop()
    assert "Traceback" not in g.output


SLOW_GRAPH = f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 240.0, n_markers: 60}}
  - name: fox
    type: foxglove_bridge
    params: {{port: 0, token: {TOKEN}, backlog: 16}}
"""


async def _stalled_client(url: str) -> list[int]:
    """Subscribes to /markers, stops reading (a tiny receive buffer, so the server feels it) until
    the bridge has dropped messages for it, then reads on; returns the frame numbers received."""
    import socket as socketlib

    port = int(url.split("?")[0].rsplit(":", 1)[1].rstrip("/"))
    sock = socketlib.socket()
    sock.setsockopt(socketlib.SOL_SOCKET, socketlib.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    async with websockets.connect(url, sock=sock, subprotocols=["foxglove.websocket.v1"], max_size=None,
                                  max_queue=1) as ws:
        channels: dict[str, dict] = {}
        while "/markers" not in channels:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        scene = channels["/markers"]
        SceneUpdate = message_class("foxglove.SceneUpdate", base64.b64decode(scene["schema"]))
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": scene["id"]}]}))
        await asyncio.sleep(4.0)  # 960 frames of ~6 kB: far beyond the socket buffers and 16 queued
        # what the buffers held comes first, then the jump, then live frames: read until 100
        # frames after a jump (or 5000 frames, when there was none)
        frames: list[int] = []
        jump_at = None
        while len(frames) < 5000 and (jump_at is None or len(frames) < jump_at + 100):
            m = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(m, bytes):
                (ent,) = SceneUpdate.FromString(m[13:]).entities
                frames.append(int(dict((kv.key, kv.value) for kv in ent.metadata)["frame"]))
                if jump_at is None and len(frames) > 1 and frames[-1] - frames[-2] > 100:
                    jump_at = len(frames)
        return frames


def test_a_client_that_stops_reading_loses_its_oldest_frames_not_the_bridge_memory(launch_graph):
    g = launch_graph(SLOW_GRAPH)
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    frames = asyncio.run(_stalled_client(url))
    steps = np.diff(frames)
    assert (steps > 0).all()  # in order, never repeated
    # one jump: what the bridge dropped while the client did not read (~960 frames sent, at most
    # the socket buffers and the 16 queued kept); after it, every frame again
    assert steps.max() > 100, steps.max()
    assert (steps[np.argmax(steps) + 1:] == 1).mean() > 0.9
    g.stop()
    dropped = int(re.search(r"(\d+) dropped for slow clients", g.output).group(1))
    print(f"stalled client: {np.argmax(steps) + 1} frames from buffers, then a jump of {steps.max()}; "
          f"bridge dropped {dropped}")
    # every drop it counts is a frame this client misses (the bus may lose others under load)
    assert 100 < dropped <= int((steps - 1).sum()), (dropped, int((steps - 1).sum()))
