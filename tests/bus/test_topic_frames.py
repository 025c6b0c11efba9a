"""A frame whose topic frame only begins with a subscribed topic never reaches that topic's input.

ZeroMQ matches subscriptions by prefix: an input subscribed to ``markers`` (the frame
``markers\\0``) is also sent a frame whose topic frame is ``markers\\0junk``. Only the exact topic
compare of the receiving port drops it; a hostile publisher on an `external:` endpoint sends some.
"""
from __future__ import annotations

import numpy as np
import pytest
import zmq

from graph_helpers import read_jsonl, wait_until
from mocapgraph.messages import MarkerFrame, encode
from mocapgraph.messages.codec import topic_frame

pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh


def _frame(number: int) -> MarkerFrame:
    return MarkerFrame(frame_number=number, rate_hz=100.0, positions=np.full((2, 3), float(number)),
                       valid=np.ones(2, bool), residual=np.zeros(2, np.float32))


def test_a_longer_topic_frame_on_a_shorter_subscription_is_dropped(launch_graph, tmp_path) -> None:
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    log = tmp_path / "log.jsonl"
    g = launch_graph(f"""\
external:
  - {{topic: markers, type: MarkerFrame, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers]}}
""")
    g.wait_ready()
    assert pub.poll(20000) and pub.recv() == b"\x01" + topic_frame("markers"), "the logger subscribes"
    seq = 0
    for i in range(20):
        seq += 1
        frames = encode("markers", _frame(1000 + i), seq, seq, "device")
        pub.send_multipart(frames)
        for junk in (b"markers\0junk", b"markers\0\0", b"markers\0" + b"x" * 100):
            seq += 1   # the same sender, numbers in order: only the topic frame is wrong
            pub.send_multipart([junk, *encode("markers", _frame(-1), seq, seq, "device")[1:]])
    wait_until(lambda: len(read_jsonl(log)) >= 20, what="the 20 real frames", graph=g)
    seq += 1
    pub.send_multipart(encode("markers", _frame(2000), seq, seq, "device"))   # a last one: the rest is through
    wait_until(lambda: read_jsonl(log)[-1]["msg"]["frame_number"] == 2000, what="the last frame", graph=g)
    assert g.stop() == 0
    got = [r["msg"]["frame_number"] for r in read_jsonl(log)]
    assert got == [1000 + i for i in range(20)] + [2000], "a frame of topic 'markers\\0...' reached 'markers'"
    assert {r["topic"] for r in read_jsonl(log)} == {"markers"}
    pub.close(0)
