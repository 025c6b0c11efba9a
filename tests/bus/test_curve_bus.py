"""CurveZMQ on tcp: a graph with keys talks encrypted, a keyless subscriber gets nothing, and a
graph that would publish beyond loopback without keys is refused."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import zmq
import zmq.auth

from graph_helpers import CommandsRunning, wait_until
from mocapgraph.cli import main
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.messages import decode
from mocapgraph.messages.codec import topic_frame


def test_curve_graph_talks_to_key_holders_only(launch_graph, tmp_path: Path, capsys) -> None:
    keys = tmp_path / "keys"
    assert main(["keys", "generate", str(keys)]) == 0
    assert "security:" in capsys.readouterr().out
    assert (keys / "graph.key_secret").stat().st_mode & 0o077 == 0
    g = launch_graph(f"""
security: {{key: {keys / 'graph.key_secret'}, authorized: {keys}}}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 50.0}}
    host: 127.0.0.1
  - name: logger
    type: topic_logger
    params: {{path: {tmp_path / 'log.jsonl'}, topics: [markers]}}
""")
    g.wait_ready()
    manifest = fetch_manifest(g.master)
    ep = manifest["topics"]["markers"]["publishers"][0]["endpoint"]
    assert ep.startswith("tcp://")
    # the graph's own subscriber (the logger) receives, and so does a tool with the keys
    wait_until(lambda: (tmp_path / "log.jsonl").exists() and (tmp_path / "log.jsonl").stat().st_size > 0,
               15, "the logger receiving over CURVE", g)
    tool = subscribe(manifest, ["markers"])
    assert tool.poll(5000), "a subscriber with the keys receives"
    env, _ = decode(tool.recv_multipart())
    assert env.sender == "pattern"
    # a subscriber without keys connects, subscribes, and receives nothing
    plain = zmq.Context.instance().socket(zmq.SUB)
    plain.setsockopt(zmq.LINGER, 0)
    plain.setsockopt(zmq.SUBSCRIBE, topic_frame("markers"))
    plain.connect(ep)
    # and one with a key pair of its own, not in the authorised folder, neither
    other = tmp_path / "other"
    assert main(["keys", "generate", str(other), "--name", "stranger"]) == 0
    pub_k, sec_k = zmq.auth.load_certificate(str(other / "stranger.key_secret"))
    graph_pub, _ = zmq.auth.load_certificate(str(keys / "graph.key"))
    stranger = zmq.Context.instance().socket(zmq.SUB)
    stranger.setsockopt(zmq.LINGER, 0)
    stranger.curve_publickey, stranger.curve_secretkey, stranger.curve_serverkey = pub_k, sec_k, graph_pub
    stranger.setsockopt(zmq.SUBSCRIBE, topic_frame("markers"))
    stranger.connect(ep)
    # the command-line tools go through the manifest's key files: echo and record work (started
    # now, so that their interpreters start up during the 2 s the strangers wait in vain)
    bag = tmp_path / "rec.mcap"
    tools = CommandsRunning([[sys.executable, "-m", "mocapgraph", "topic", "echo", "markers", "-n", "2", "--json",
                              "--timeout", "20"],
                             [sys.executable, "-m", "mocapgraph", "bag", "record", "markers", "-o", str(bag),
                              "--duration", "2"]], env=g.env)
    time.sleep(2.0)
    assert not plain.poll(100) and not stranger.poll(100)
    assert tool.poll(1000), "the key holder still receives meanwhile"
    for s in (plain, stranger, tool):
        s.close(0)
    echo, record = tools.results(timeout=60)
    assert echo.returncode == 0 and echo.stdout.count("\n") >= 2, echo.stderr
    assert record.returncode == 0 and bag.stat().st_size > 1000, record.stdout + record.stderr


def test_publishing_beyond_loopback_needs_keys_or_insecure(tmp_path: Path, capsys) -> None:
    graph = tmp_path / "g.yaml"
    node = "nodes:\n  - name: pattern\n    type: marker_test_pattern\n    host: 0.0.0.0\n"
    graph.write_text(node)
    assert main(["graph", "check", str(graph)]) == 2
    err = capsys.readouterr().err
    assert "reachable from other machines" in err and "security:" in err and err.count("\n") == 1
    graph.write_text("security: {insecure: true}\n" + node)
    assert main(["graph", "check", str(graph)]) == 0
    graph.write_text(f"security: {{key: {tmp_path / 'none.key_secret'}, authorized: {tmp_path}}}\n" + node)
    assert main(["graph", "check", str(graph)]) == 2
    assert "cannot read key" in capsys.readouterr().err


def test_bag_play_refuses_to_bind_beyond_loopback_without_insecure(tmp_path: Path, capsys) -> None:
    import numpy as np

    from mocapgraph.bag.writer import BagWriter
    from mocapgraph.messages import MarkerFrame

    bag = tmp_path / "b.mcap"
    with BagWriter(str(bag)) as w:
        w.write("markers", MarkerFrame(frame_number=0, rate_hz=1.0, positions=np.zeros((1, 3)),
                                       valid=np.ones(1, bool), residual=np.zeros(1, np.float32)), seq=1, capture_ns=0)
    assert main(["bag", "play", str(bag), "--bind", "tcp://0.0.0.0:0"]) == 2
    assert "--insecure" in capsys.readouterr().err
