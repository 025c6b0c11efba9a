"""A respawned solver is a new stream: its first poses reach the viewer at once, not after its
numbers pass the old process's last one (which at 30 Hz took minutes)."""
from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import socket
import time

import pytest

from graph_helpers import node_pids, read_jsonl, wait_until
from mocapgraph.viewer.wire import decode_bundle

websockets_client = pytest.importorskip("websockets.asyncio.client")
pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh

RATE_HZ = 30.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ws_url(graph) -> str:
    url = re.search(r"viewer at (\S+)", graph.wait_for("viewer at ", 30)).group(1)
    base, _, query = url.partition("?")
    return base.replace("http://", "ws://").rstrip("/") + "/ws?" + query


async def _poses(ws, out: list, until) -> None:
    """(receive wall ns, seq, publish ns) of every actor_pose record from the solver, acking each bundle."""
    while not until():
        msg = await ws.recv()
        if isinstance(msg, bytes):
            now = time.time_ns()
            for r in decode_bundle(msg)[1]:
                if r["topic"] == "actor_pose" and r["sender"] == "solver":
                    out.append((now, r["seq"], int(r["publish_ms"] * 1e6)))
            await ws.send("a")


def test_a_respawned_solver_reaches_the_viewer_within_a_second_of_its_first_frame(launch_graph, tmp_path) -> None:
    log = tmp_path / "log.jsonl"
    g = launch_graph(f"""
nodes:
  - name: reader
    type: synthetic_actor
    params: {{rate_hz: {RATE_HZ}}}
    remap: {{ground_truth_model: skeleton_model}}
  - name: solver
    type: frame_solver
    respawn: true
    respawn_delay: 0.1
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [actor_pose]}}
  - name: viz
    type: visualizer
    params: {{port: {_free_port()}, max_rate_hz: 60.0}}
""")
    g.wait_ready(60)
    url = _ws_url(g)
    seen: list = []

    async def run() -> None:
        async with websockets_client.connect(url) as ws:
            json.loads(await ws.recv())   # hello
            # the old process well ahead: 4 s at 30 Hz, so the new one starts 120 numbers below it
            # (twice the 2 s of numbers the new one is watched for below)
            await asyncio.wait_for(_poses(ws, seen, lambda: len(seen) and seen[-1][1] > 4 * RATE_HZ), 60)
            old_last = seen[-1][1]
            killed_ns = time.time_ns()
            os.kill(node_pids(g)["solver"], signal.SIGKILL)

            def new_ones() -> list:
                return [p for p in seen if p[2] > killed_ns]

            # the new process: 3 s of its poses at most (a loaded machine), or until it has 2 s of them
            try:
                await asyncio.wait_for(_poses(ws, seen, lambda: len(new_ones()) > 0 and new_ones()[-1][1] > 2 * RATE_HZ),
                                       30)
            except asyncio.TimeoutError:
                pass
            return old_last, killed_ns

    old_last, killed_ns = asyncio.run(run())
    g.wait_for("respawning solver")
    new = [p for p in seen if p[2] > killed_ns]
    assert new, f"no pose of the respawned solver reached the viewer (the old one was at {old_last}):\n{g.output}"
    # the new process's first frame: its lowest number the logger got, back to number 1 at 30 Hz
    logged = [r for r in read_jsonl(log) if r["publish_ns"] > killed_ns]
    assert logged, "the logger got none of the respawned solver's poses"
    first = min(logged, key=lambda r: r["seq"])
    first_ns = first["publish_ns"] - (first["seq"] - 1) * 1e9 / RATE_HZ
    took = (new[0][0] - first_ns) / 1e9
    print(f"old stream ended at {old_last}; the new one's first pose in the viewer: seq {new[0][1]}, "
          f"{took:.3f} s after its first frame; the logger's first: seq {first['seq']}")
    assert took <= 1.0
    assert new[0][1] < old_last, "the new stream numbers from 1 again (else this test shows nothing)"
    # and the stream goes on: the logger has it all, in order, from the new stream's first frame on
    seqs = [r["seq"] for r in logged]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))) and len(seqs) >= RATE_HZ
    assert g.stop() == 0
