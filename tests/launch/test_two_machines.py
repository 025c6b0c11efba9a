"""One graph file, two launchers (`--machine`), CurveZMQ between them: markers flow across."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from graph_helpers import read_jsonl, wait_until
from mocapgraph.cli import main

pytestmark = pytest.mark.slow  # two launchers


def _ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def test_one_graph_split_across_two_launchers(tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys"
    assert main(["keys", "generate", str(keys)]) == 0
    p_capture, p_render = _ports(2)
    log = tmp_path / "render.jsonl"
    graph = tmp_path / "split.yaml"
    graph.write_text(f"""
security: {{key: {keys / 'graph.key_secret'}, authorized: {keys}}}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 50.0}}
    machine: capture
    host: 127.0.0.1
    port: {p_capture}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers]}}
    machine: render
    host: 127.0.0.1
    port: {p_render}
""")
    assert main(["graph", "check", str(graph)]) == 0
    capsys.readouterr()
    procs = []
    try:
        for machine in ("render", "capture"):
            env = dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp_path / ('m-' + machine + uuid.uuid4().hex[:4])}")
            procs.append(subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph), "--machine",
                                           machine], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                          text=True, start_new_session=True))
        wait_until(lambda: len(read_jsonl(log, "markers")) > 20, 60, "markers from the capture launcher")
        time.sleep(0.5)
        assert all(p.poll() is None for p in procs)
    finally:
        outs = []
        for p in procs:
            p.send_signal(2)
            outs.append(p.communicate(timeout=30)[0])
    assert "1 nodes ready" in outs[0] and "1 nodes ready" in outs[1], outs
    assert "Traceback" not in "".join(outs)
    # a launcher told to run a machine no node names says so
    assert main(["launch", str(graph), "--machine", "kitchen"]) == 2
    assert "no node runs on machine 'kitchen'" in capsys.readouterr().err
