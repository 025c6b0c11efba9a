"""The manifest endpoint survives malformed requests (launcher and `bag play`); a run directory
that is not safely ours is refused by the launcher and by the tools."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from graph_helpers import run_concurrently, wait_until
from mocapgraph.bag.writer import BagWriter
from mocapgraph.bus.manifest import fetch_manifest
from mocapgraph.messages import MarkerFrame

PATTERN = "nodes:\n  - name: pattern\n    type: marker_test_pattern\n    params: {rate_hz: 50.0}\n"


def _hostile_requests(master: str) -> None:
    """Two-part, envelope-less, oversized and unknown requests, as a stranger would send them."""
    ctx = zmq.Context.instance()
    d = ctx.socket(zmq.DEALER)
    d.setsockopt(zmq.LINGER, 0)
    d.connect(master)
    d.send_multipart([b"", b"manifest", b"and more"])  # a REQ envelope around two parts
    d.send_multipart([b"manifest", b"x"])  # no envelope at all
    d.send_multipart([b"", b"x" * 100_000])  # oversized: the peer is cut off
    d2 = ctx.socket(zmq.DEALER)
    d2.setsockopt(zmq.LINGER, 0)
    d2.connect(master)
    d2.send_multipart([b"", b"give me everything"])
    assert d2.poll(5000), "an unknown one-part request gets an error reply"
    assert b"unknown request" in d2.recv_multipart()[-1]
    r = ctx.socket(zmq.REQ)
    r.setsockopt(zmq.LINGER, 0)
    r.connect(master)
    r.send_multipart([b"manifest", b"extra"])  # REQ sends both parts inside its envelope
    time.sleep(0.3)
    for s in (d, d2, r):
        s.close(0)


def test_a_malformed_manifest_request_leaves_the_graph_running(launch_graph) -> None:
    g = launch_graph(PATTERN)
    g.wait_ready()
    _hostile_requests(g.master)
    time.sleep(0.5)
    assert g.proc.poll() is None, g.output
    assert [n["name"] for n in fetch_manifest(g.master)["nodes"]] == ["pattern"]
    assert "Traceback" not in g.output


def test_bag_play_manifest_survives_malformed_requests(tmp_path: Path) -> None:
    bag = tmp_path / "b.mcap"
    with BagWriter(str(bag)) as w:
        for i in range(100):
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=100.0, positions=np.zeros((2, 3)),
                                           valid=np.ones(2, bool), residual=np.zeros(2, np.float32)),
                    seq=i + 1, capture_ns=i * 10_000_000)
    master = f"ipc://{tmp_path / 'master'}"
    env = dict(os.environ, MOCAPGRAPH_MASTER=master, PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "mocapgraph", "bag", "play", str(bag), "--loop"], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wait_until(lambda: _answers(master), 30, "bag play serving its manifest")
        _hostile_requests(master)
        time.sleep(0.5)
        assert p.poll() is None, p.stdout.read() if p.poll() is not None else ""
        assert "markers" in fetch_manifest(master)["topics"]
    finally:
        p.terminate()
        out = p.communicate(timeout=20)[0]
    assert "Traceback" not in out, out


def _answers(master: str) -> bool:
    try:
        fetch_manifest(master, timeout_s=0.5)
        return True
    except Exception:  # noqa: BLE001 - not up yet
        return False


@pytest.fixture
def short_tmp():
    """A folder with a short path, removed after the test: the run directory's socket paths must
    fit the OS's 107 bytes whatever the test runner's own temporary folder (a worker's is longer)."""
    tmp = Path(tempfile.mkdtemp(prefix="mg-", dir="/tmp"))
    yield tmp
    shutil.rmtree(tmp, ignore_errors=True)


@pytest.mark.parametrize("how", ["foreign_owner", "world_writable"])
def test_an_unsafe_run_directory_is_refused(tmp_path: Path, short_tmp: Path, how: str) -> None:
    tmp = short_tmp
    run_dir = tmp / f"mocapgraph-{os.getuid()}"
    run_dir.mkdir(parents=True)
    if how == "foreign_owner":
        if os.getuid() != 0:
            pytest.skip("making a directory another user owns needs root")
        os.chown(run_dir, 65534, 65534)
        run_dir.chmod(0o700)
        words = "belongs to uid 65534"
    else:
        run_dir.chmod(0o777)
        words = "others may write into it"
    graph = tmp_path / "g.yaml"
    graph.write_text(PATTERN)
    env = {k: v for k, v in os.environ.items() if k != "MOCAPGRAPH_MASTER"}
    env["TMPDIR"] = str(tmp)
    # the launcher and a tool, both refused: independent, so run at once (start-ups share the cores)
    r, tool = run_concurrently([[sys.executable, "-m", "mocapgraph", "launch", str(graph)],
                                [sys.executable, "-m", "mocapgraph", "topic", "list"]], timeout=60, env=env)
    out = r.stdout + r.stderr
    assert r.returncode != 0 and words in out and "Traceback" not in out, out
    assert not (run_dir / "master").exists()
    assert tool.returncode == 2 and words in tool.stderr and "Traceback" not in tool.stderr, tool.stderr
