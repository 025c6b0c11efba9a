"""Two machines on one: network namespaces joined by a veth pair, the demo-style graph split with
--machine. Over CurveZMQ the marker labels never appear in a capture of the link and a keyless
subscriber gets nothing; the same graph with `insecure: true` shows the labels (the capture works).

Needs root and network namespaces (CI runs as root); skipped cleanly elsewhere. Addresses are used
only inside the namespaces made here.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from graph_helpers import read_jsonl, wait_until
from mocapgraph.cli import main

pytestmark = pytest.mark.slow  # two network namespaces

A_IP, B_IP = "10.231.77.1", "10.231.77.2"
CAPTURE = r"""
import socket, sys, time
s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(3))
s.bind((sys.argv[1], 0))
s.settimeout(0.2)
out = open(sys.argv[2], "wb")
t_end = time.monotonic() + float(sys.argv[3])
while time.monotonic() < t_end:
    try:
        out.write(s.recv(65535))
    except socket.timeout:
        pass
    out.flush()
"""
KEYLESS = r"""
import sys, zmq
s = zmq.Context().socket(zmq.SUB)
s.setsockopt(zmq.SUBSCRIBE, b"")
s.connect(sys.argv[1])
print("got" if s.poll(3000) else "nothing", flush=True)
"""


def _sh(*cmd: str) -> None:
    subprocess.run(cmd, check=True, capture_output=True, timeout=20)


@pytest.fixture
def two_namespaces():
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2")
    tag = uuid.uuid4().hex[:6]
    a, b = f"mgA{tag}", f"mgB{tag}"
    try:
        _sh("ip", "netns", "add", a)
        _sh("ip", "netns", "add", b)
    except (subprocess.CalledProcessError, OSError) as exc:
        subprocess.run(["ip", "netns", "del", a], capture_output=True)
        pytest.skip(f"network namespaces not allowed here ({exc})")
    try:
        _sh("ip", "link", "add", f"va{tag}", "netns", a, "type", "veth", "peer", "name", f"vb{tag}", "netns", b)
        for ns, dev, ip in ((a, f"va{tag}", A_IP), (b, f"vb{tag}", B_IP)):
            _sh("ip", "-n", ns, "addr", "add", f"{ip}/24", "dev", dev)
            _sh("ip", "-n", ns, "link", "set", dev, "up")
            _sh("ip", "-n", ns, "link", "set", "lo", "up")
        yield a, b, f"va{tag}"
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=20)


def _run_split(tmp: Path, ns_a: str, ns_b: str, dev_a: str, security: str) -> tuple[bytes, str, list[str]]:
    log = tmp / "render.jsonl"
    graph = tmp / "split.yaml"
    graph.write_text(f"""
security: {security}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 50.0}}
    machine: capture
    host: {A_IP}
    port: 47001
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers, marker_layout]}}
    machine: render
    host: {B_IP}
    port: 47002
""")
    pcap = tmp / "link.bin"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    cap = subprocess.Popen(["ip", "netns", "exec", ns_a, sys.executable, "-c", CAPTURE, dev_a, str(pcap), "25"])
    procs = []
    try:
        time.sleep(0.5)
        for ns, machine in ((ns_b, "render"), (ns_a, "capture")):
            e = dict(env, MOCAPGRAPH_MASTER=f"ipc://{tmp / ('m-' + machine)}")
            procs.append(subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, "-m", "mocapgraph", "launch",
                                           str(graph), "--machine", machine], env=e, stdout=subprocess.PIPE,
                                          stderr=subprocess.STDOUT, text=True))
        wait_until(lambda: len(read_jsonl(log, "markers")) > 30, 60, "markers across the veth link")
        keyless = subprocess.run(["ip", "netns", "exec", ns_b, sys.executable, "-c", KEYLESS,
                                  f"tcp://{A_IP}:47001"], capture_output=True, text=True, timeout=30).stdout.strip()
    finally:
        outs = []
        for p in procs:
            p.send_signal(2)
            outs.append(p.communicate(timeout=30)[0])
        cap.terminate()
        cap.wait(10)
    return pcap.read_bytes(), keyless, outs


def test_labels_never_cross_the_link_in_clear(two_namespaces, tmp_path: Path) -> None:
    ns_a, ns_b, dev_a = two_namespaces
    keys = tmp_path / "keys"
    assert main(["keys", "generate", str(keys)]) == 0
    (tmp_path / "curve").mkdir()
    wire, keyless, outs = _run_split(tmp_path / "curve", ns_a, ns_b, dev_a,
                                     f"{{key: {keys / 'graph.key_secret'}, authorized: {keys}}}")
    print(f"CurveZMQ: {len(wire)} bytes captured on the link; keyless subscriber: {keyless}")
    assert len(wire) > 20_000, outs  # markers did cross
    assert b"test_pattern" not in wire and b"marker_layout" not in wire and b"MarkerFrame" not in wire
    assert keyless == "nothing"
    (tmp_path / "plain").mkdir()
    wire, keyless, outs = _run_split(tmp_path / "plain", ns_a, ns_b, dev_a, "{insecure: true}")
    print(f"plaintext: {len(wire)} bytes captured; keyless subscriber: {keyless}")
    assert b"test_pattern" in wire and keyless == "got"  # the capture sees what is not encrypted
