"""The Foxglove bridge holds a bounded number of clients (stalled ones hold bounded memory, given
back when they leave) and logs connections and refusals at a bounded rate."""
from __future__ import annotations

import asyncio
import re
import socket
import time

import pytest
import websockets
from websockets.exceptions import InvalidStatus

from graph_helpers import node_pids

pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh

TOKEN = "s3cret-token"
MAX_CLIENTS = 4
GRAPH = f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 240.0, n_markers: 60}}
  - name: fox
    type: foxglove_bridge
    params: {{port: 0, token: {TOKEN}, max_clients: {MAX_CLIENTS}}}
"""


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


async def _stalled(url: str, port: int):
    """A client that subscribes to /markers and then reads nothing (tiny receive buffer, one queued
    message): the bridge's queue for it fills. Returns the open connection."""
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", port))
    ws = await websockets.connect(url, sock=sock, subprotocols=["foxglove.websocket.v1"], max_size=None, max_queue=1)
    import json

    while True:
        msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
        ch = {c["topic"]: c for c in msg.get("channels", [])}
        if "/markers" in ch:
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ch["/markers"]["id"]}]}))
            return ws


def test_stalled_clients_are_capped_hold_bounded_memory_and_give_it_back(launch_graph) -> None:
    g = launch_graph(GRAPH)
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    port = int(url.split("?")[0].rsplit(":", 1)[1].rstrip("/"))
    pid = node_pids(g)["fox"]
    time.sleep(1.0)
    rss0 = _rss_mb(pid)

    async def run():
        clients, refused = [], []
        for _ in range(10):
            try:
                clients.append(await _stalled(url, port))
            except InvalidStatus as exc:
                refused.append(exc.response.status_code)
        await asyncio.sleep(5.0)   # 1200 frames of ~6 kB each to every stalled one
        rss1 = _rss_mb(pid)
        for ws in clients:
            ws.transport.abort()
        await asyncio.sleep(2.0)
        again = await _stalled(url, port)   # room again once they left
        again.transport.abort()
        return len(clients), refused, rss1

    n, refused, rss1 = asyncio.run(run())
    t_end = time.monotonic() + 2.0     # given back within 2 s of the last one leaving (read until then)
    while (rss2 := _rss_mb(pid)) - rss0 > 15 and time.monotonic() < t_end:
        time.sleep(0.05)
    print(f"{n} stalled clients accepted, {len(refused)} refused ({set(refused)}); bridge RSS {rss0:.1f} -> "
          f"{rss1:.1f} MB with them, {rss2:.1f} MB after they left")
    assert n == MAX_CLIENTS and refused == [503] * (10 - MAX_CLIENTS)
    assert rss1 - rss0 <= MAX_CLIENTS * 4 + 30, "each stalled client holds 4 MB of queue at most"
    assert rss2 - rss0 <= 15, "the memory is given back"
    assert "clients are connected, the most this bridge serves" not in g.output   # the reason goes to the client
    g.stop()
    assert "'full': 6" in g.output


def test_3000_token_guesses_give_a_bounded_number_of_log_lines(launch_graph) -> None:
    g = launch_graph(GRAPH)
    g.wait_ready()
    url = re.search(r"(ws://\S+)", g.wait_for("foxglove bridge at ")).group(1)
    base = url.split("?")[0]
    before = len(g.output.splitlines())

    async def guess(i: int) -> int:
        try:
            async with websockets.connect(f"{base}?token=guess{i}", subprotocols=["foxglove.websocket.v1"]):
                return 101
        except InvalidStatus as exc:
            return exc.response.status_code

    async def run():
        codes = []
        for k in range(0, 3000, 50):
            codes += await asyncio.gather(*(guess(i) for i in range(k, k + 50)))
        return codes

    t0 = time.monotonic()
    codes = asyncio.run(run())
    took = time.monotonic() - t0
    time.sleep(1.0)
    lines = [l for l in g.output.splitlines()[before:] if l.startswith("[fox]")]
    print(f"3000 wrong tokens in {took:.1f} s: {len(lines)} log lines; last: {lines[-1] if lines else None}")
    assert codes == [403] * 3000
    assert len(lines) <= 12 * (took / 5.0 + 2), lines[-5:]
    g.stop()
    assert "'token': 3000" in g.output, "every refusal is counted, none lost to the rate limit"
