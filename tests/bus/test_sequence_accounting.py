"""Sequence accounting on real edges: gaps counted exactly, a restarted sender delivered and
reported (not dropped as duplicates), latched resends delivered once, in nodes and in bags."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest
import zmq

from graph_helpers import node_pids, read_jsonl, wait_until
from mocapgraph.bag.reader import BagReader
from mocapgraph.messages import MarkerFrame, MarkerLayout, encode
from mocapgraph.messages.codec import topic_frame

# What the test's own publisher sends, as (sequence number, resend): frames 11-13 dropped on
# purpose, frame 20 resent (as a latched value is to every subscriber when another joins), then the
# sender restarts at 1 and loses frame 6 of its new stream.
SENT = ([(s, False) for s in range(1, 11)] + [(s, False) for s in range(14, 21)] + [(20, True)]
        + [(s, False) for s in range(1, 6)] + [(7, False)])
DELIVERED = list(range(1, 11)) + list(range(14, 21)) + list(range(1, 6)) + [7]
GAPS = 3 + 1  # 11..13 in the first stream, 6 in the second; the restart itself is not loss


pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh


def frame(seq: int) -> MarkerFrame:
    return MarkerFrame(frame_number=seq, rate_hz=100.0, positions=np.full((2, 3), float(seq)),
                       valid=np.ones(2, bool), residual=np.zeros(2, np.float32))


def diagnostics_of(g, node: str) -> dict:
    r = g.cli("topic", "echo", "diagnostics", "--json", "-n", "4", "--timeout", "10")
    for line in r.stdout.splitlines():
        d = json.loads(line)["msg"]
        if d["node"] == node:
            return d
    return {}


def test_gaps_restarts_and_resends_from_a_publisher_that_drops_on_purpose(launch_graph, tmp_path) -> None:
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.XPUB)
    pub.setsockopt(zmq.XPUB_VERBOSE, 1)  # one subscription message per subscriber
    pub.setsockopt(zmq.LINGER, 0)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    log, bag = tmp_path / "log.jsonl", tmp_path / "seq.mcap"
    g = launch_graph(f"""\
external:
  - {{topic: markers, type: MarkerFrame, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers]}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers]}}
""")
    g.wait_ready()
    # `bag record` too: its own accounting (the recorder node's is gated by the runtime's first)
    cli_bag = tmp_path / "cli.mcap"
    record = subprocess.Popen([sys.executable, "-m", "mocapgraph", "bag", "record", "-o", str(cli_bag), "markers",
                               "--duration", "6"], env=g.env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True)
    subscribed = 0
    while subscribed < 3:  # the logger, the recorder node and `bag record`
        assert pub.poll(20000), "a subscriber never subscribed"
        subscribed += pub.recv() == b"\x01" + topic_frame("markers")
    sent: dict[int, list[bytes]] = {}
    for seq, resend in SENT:
        if not resend:  # a resend is the same bytes again, as a latched value's is
            sent[seq] = [bytes(f) for f in encode("markers", frame(seq), seq, seq * 1_000_000, "device")]
        pub.send_multipart(sent[seq])
    wait_until(lambda: len(read_jsonl(log)) >= len(DELIVERED), what="the delivered frames", graph=g)
    d = wait_until(lambda: (d := diagnostics_of(g, "logger")) and d["edge_received"] == [len(DELIVERED)] and d,
                   what="the logger's diagnostics", graph=g)
    assert d["edge_senders"] == ["device"] and d["edge_gaps"] == [GAPS]
    g.wait_for("[logger] INFO markers from device: the sender restarted (sequence 1 after 20)")
    assert g.stop() == 0
    recs = read_jsonl(log)
    assert [r["seq"] for r in recs] == DELIVERED
    assert [r["msg"]["frame_number"] for r in recs] == DELIVERED  # the frames themselves, not a resend
    out, _ = record.communicate(timeout=30)
    assert record.returncode == 0, out
    for path in (bag, cli_bag):
        with BagReader(path) as r:
            assert [e.seq for e, _ in r.decoded("markers")] == DELIVERED, path
            assert r.summary().losses == {"markers": GAPS}, path
    pub.close(0)


def test_a_killed_and_respawned_publisher_is_a_new_stream_and_latched_values_arrive_once(launch_graph,
                                                                                      tmp_path) -> None:
    log = tmp_path / "log.jsonl"
    g = launch_graph(f"""\
nodes:
  - name: pattern
    type: marker_test_pattern
    respawn: true
    respawn_delay: 0.1
    params: {{rate_hz: 200.0, n_markers: 3}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers, marker_layout]}}
""")
    g.wait_ready()

    def seqs(topic: str) -> list[int]:
        return [r["seq"] for r in read_jsonl(log, topic)]

    # A late joiner makes the pattern resend its latched layout to every subscriber of it: the
    # logger, which has it already, drops the resend.
    r = g.cli("topic", "echo", "marker_layout", "-n", "1", "--json", "--timeout", "10")
    assert r.returncode == 0 and json.loads(r.stdout)["msg"]["labels"] == ["P0", "P1", "P2"]
    wait_until(lambda: len(seqs("markers")) > 300, what="frames of the first pattern process", graph=g)
    os.kill(node_pids(g)["pattern"], signal.SIGKILL)
    g.wait_for("respawning pattern")
    wait_until(lambda: 1 in seqs("markers")[1:] and len(seqs("markers")) - seqs("markers").index(1, 1) > 50,
               what="frames of the respawned pattern", graph=g)
    g.wait_for("[logger] INFO markers from pattern: the sender restarted (sequence 1 after")
    d = wait_until(lambda: diagnostics_of(g, "logger"), what="the logger's diagnostics", graph=g)
    assert g.stop() == 0
    got = seqs("markers")
    k = got.index(1, 1)  # where the second process's stream begins
    assert got[:k] == list(range(1, k + 1))  # nothing lost, nothing dropped
    assert got[k:k + 50] == list(range(1, 51))  # the new stream from its first frame
    # Each process's layout exactly once: the resend to the late `topic echo` was not logged again.
    assert seqs("marker_layout") == [1, 1]
    assert d["edge_gaps"][d["edge_topics"].index("markers")] == 0
