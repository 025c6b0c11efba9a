"""Seeking past the end clamps to the end, and a looping player keeps looping (issue 30, item 6).

A real bag player process gets ``seek {"position_s": 1e7}`` (what the viewer lets through) from
an ``external:`` publisher; before, it found nothing past the end, called itself finished and
left the graph with exit 0. The bag's last message is a diagnostics record that the player does
not play, so a seek to the bag's end finds none of the played topics there either.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import zmq

from graph_helpers import read_jsonl, wait_until
from mocapgraph.messages import MarkerFrame, NodeCommand, NodeStatus, encode
from mocapgraph.messages.codec import topic_frame

N = 240  # 2 s at 120 Hz


def _bag(path: Path) -> None:
    from mocapgraph.bag.writer import BagWriter

    with BagWriter(str(path)) as w:
        for i in range(N):
            w.write("markers", MarkerFrame(frame_number=i, rate_hz=120.0, positions=np.zeros((4, 3)),
                                           valid=np.ones(4, bool), residual=np.zeros(4, np.float32)),
                    seq=i + 1, capture_ns=int(i * 1e9 / 120), publish_ns=int(i * 1e9 / 120))
        # recorded last, not played: nothing of the played topics lies at the bag's very end
        w.write("diagnostics", NodeStatus(node="rec", state="ok"), seq=1, capture_ns=int(3e9), publish_ns=int(3e9))


class Sender:
    def __init__(self) -> None:
        self.sock = zmq.Context.instance().socket(zmq.XPUB)
        self.port = self.sock.bind_to_random_port("tcp://127.0.0.1")
        self.seq = 0

    def wait_subscriber(self) -> None:
        assert self.sock.poll(60000) and self.sock.recv() == b"\x01" + topic_frame("player_command")

    def send(self, command: str, **args) -> None:
        self.seq += 1
        msg = NodeCommand(target="", command=command, args_json=json.dumps(args))
        self.sock.send_multipart([bytes(f) for f in encode("player_command", msg, self.seq, time.time_ns(), "probe")])


def _graph(sender: Sender, bag: Path, log: Path, loop: bool) -> str:
    return f"""\
external:
  - {{topic: player_command, type: NodeCommand, endpoint: "tcp://127.0.0.1:{sender.port}"}}
nodes:
  - name: player
    type: bag_player
    params: {{file: "{bag}", loop: {str(loop).lower()}, stop_at_end: true}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers, player_status]}}
"""


def _frames(log: Path) -> list[int]:
    return [r["msg"]["frame_number"] for r in read_jsonl(log, "markers")]


def test_a_looping_player_seeked_past_the_end_keeps_looping(launch_graph, tmp_path):
    bag, log = tmp_path / "b.mcap", tmp_path / "log.jsonl"
    _bag(bag)
    s = Sender()
    g = launch_graph(_graph(s, bag, log, loop=True))
    g.wait_ready()
    s.wait_subscriber()
    wait_until(lambda: len(_frames(log)) > 20, what="playing", graph=g)
    for position in (1e7, 1e300, 2.5):
        n = len(_frames(log))
        s.send("seek", position_s=position)
        # within one pass (2 s) it is back at the start of the bag, and it goes on
        wait_until(lambda: 0 in _frames(log)[n + 1:] and len(_frames(log)) > n + 60, timeout=20,
                   what=f"a new pass after seek {position}", graph=g)
    assert g.proc.poll() is None and "exited" not in g.output, g.output
    status = json.loads([r for r in read_jsonl(log, "player_status")][-1]["msg"]["data_json"])
    assert status["position_s"] <= status["duration_s"] + 1e-6
    assert g.stop() == 0


def test_a_player_seeked_past_the_end_without_loop_finishes_at_the_end(launch_graph, tmp_path):
    bag, log = tmp_path / "b.mcap", tmp_path / "log.jsonl"
    _bag(bag)
    s = Sender()
    g = launch_graph(_graph(s, bag, log, loop=False))
    g.wait_ready()
    s.wait_subscriber()
    wait_until(lambda: len(_frames(log)) > 20, what="playing", graph=g)
    s.send("seek", position_s=1e7)
    g.wait_for("node player exited with code 0", timeout=20)
    frames = _frames(log)
    assert frames == list(range(len(frames))) and len(frames) < N, frames[-5:]   # nothing replayed or skipped back
    finished = [r["msg"] for r in read_jsonl(log, "player_status") if r["msg"]["state"] == "finished"]
    done = json.loads(finished[-1]["data_json"]) if finished else {}
    assert done and done["position_s"] <= done["duration_s"] + 1e-6, done   # at the end, not 1e7 s in
    assert "Traceback" not in g.output
