"""A node that stops (SIGSTOP) is reported stalled by the launcher and in the manifest, then back."""
from __future__ import annotations

import os
import signal
import time

import pytest

from graph_helpers import node_pids, wait_until
from mocapgraph.bus.manifest import fetch_manifest


pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh


def test_a_stopped_node_is_reported_stalled_and_resumed(launch_graph) -> None:
    g = launch_graph("""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {rate_hz: 50.0}
  - name: logger
    type: topic_logger
    params: {path: log.jsonl, topics: [markers]}
""")
    g.wait_ready()
    pid = node_pids(g)["pattern"]
    time.sleep(1.5)
    assert "stalled" not in g.output
    os.kill(pid, signal.SIGSTOP)
    t0 = time.monotonic()
    try:
        line = g.wait_for("node pattern stalled", timeout=10)
        took = time.monotonic() - t0
        stalled = {n["name"]: n["stalled"] for n in fetch_manifest(g.master)["nodes"]}
    finally:
        os.kill(pid, signal.SIGCONT)
    print(f"reported after {took:.1f} s: {line}")
    assert 2.0 <= took <= 6.0  # 3 s of silence after the last 1 Hz diagnostics, on a loaded machine
    assert stalled == {"pattern": True, "logger": False}
    g.wait_for("node pattern is responding again", timeout=10)
    wait_until(lambda: not any(n["stalled"] for n in fetch_manifest(g.master)["nodes"]), 10, "stall cleared", g)
    assert "logger stalled" not in g.output
