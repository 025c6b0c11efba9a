"""Nodes composed in one process (``process:``): delivery without ZeroMQ, intact and complete, one
node stopping alone, the process crashing and respawning as a whole, no handler re-entered, each
subscriber's own read-only copy, the graph file's errors, and the composed live pipeline."""
from __future__ import annotations

import os
import signal
import threading
import time

import numpy as np
import pytest

from graph_helpers import assert_pattern_frame, graph_error, node_pids, pid_alive, read_jsonl, wait_until
from mocapgraph.bag.reader import BagReader
from mocapgraph.bus.node import Input, Node, Output, Wiring
from mocapgraph.bus.process import serve
from mocapgraph.formats.retarget_setup import build, source_from_model
from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.retarget.retargeter import RetargetOptions
from mocapgraph.kinematics.model import save_model
from mocapgraph.kinematics.synthetic.actor import SyntheticActor
from mocapgraph.cli.graph_cmds import to_text
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph
from mocapgraph.messages import MarkerFrame, NodeStatus


@pytest.mark.timing
def test_composed_nodes_get_every_frame_intact_and_the_rest_of_the_graph_too(launch_graph, tmp_path) -> None:
    g = launch_graph(f"""\
nodes:
  - name: pattern
    type: marker_test_pattern
    process: pipe
    params: {{rate_hz: 200.0, n_markers: 6, count: 150, missing_every: 5}}
  - name: logger
    type: topic_logger
    process: pipe
    params: {{path: {tmp_path / 'in.jsonl'}, topics: [markers, marker_layout]}}
  - name: outside
    type: topic_logger
    params: {{path: {tmp_path / 'out.jsonl'}, topics: [markers, marker_layout]}}
""")
    g.wait_ready()
    assert "3 nodes ready in" in g.output and "in 2 processes" in g.output
    pids = node_pids(g)
    assert pids["pattern"] == pids["logger"] != pids["outside"]
    # the source finishes; its process serves the logger on, which still gets everything
    g.wait_for("node pattern stopped (process pipe serves its other nodes on)", timeout=30)
    wait_until(lambda: len(read_jsonl(tmp_path / "in.jsonl", "markers")) == 150, what="the in-process log")
    assert pid_alive(pids["logger"])
    assert g.stop() == 0
    for name in ("in.jsonl", "out.jsonl"):
        recs = read_jsonl(tmp_path / name, "markers")
        assert [r["seq"] for r in recs] == list(range(1, 151)), name
        for r in recs:
            assert_pattern_frame(r, 6, 200.0, missing_every=5)
        layout = read_jsonl(tmp_path / name, "marker_layout")
        assert len(layout) == 1 and layout[0]["msg"]["labels"] == [f"P{i}" for i in range(6)], name


@pytest.mark.timing
def test_a_process_that_dies_is_respawned_whole_and_its_nodes_take_up_again(launch_graph, tmp_path) -> None:
    log = tmp_path / "log.jsonl"
    g = launch_graph(f"""\
nodes:
  - name: pattern
    type: marker_test_pattern
    process: pipe
    respawn: true
    respawn_delay: 0.2
    params: {{rate_hz: 100.0, n_markers: 3}}
  - name: logger
    type: topic_logger
    process: pipe
    respawn: true
    respawn_delay: 0.2
    params: {{path: {log}, topics: [markers, marker_layout]}}
""")
    g.wait_ready()
    wait_until(lambda: len(read_jsonl(log, "markers")) > 20, what="frames in the log")
    old = node_pids(g)["pattern"]
    os.kill(old, signal.SIGKILL)
    g.wait_for("process pipe (pattern, logger) exited with code -9")
    g.wait_for("respawning process pipe (pattern, logger) (restart 1)")
    wait_until(lambda: node_pids(g)["pattern"] not in (old, None), what="a new pid")
    pids = node_pids(g)
    assert pids["pattern"] == pids["logger"]
    # the new logger gets the new pattern's latched layout in process, and its frames from 1 again
    wait_until(lambda: len(read_jsonl(log, "marker_layout")) >= 2, what="the layout again")
    wait_until(lambda: [r["seq"] for r in read_jsonl(log, "markers")].count(5) >= 2, what="a new stream")
    assert g.stop() == 0


def test_process_keys_that_cannot_work_are_graph_errors(tmp_path) -> None:
    def error(text: str) -> str:
        return graph_error(tmp_path / "g.yaml", text)

    msg = error("""\
nodes:
  - name: a
    type: marker_test_pattern
    process: p
  - name: b
    type: topic_logger
    process: p
    respawn: true
    params: {topics: [markers]}
""")
    assert msg.startswith(f"{tmp_path / 'g.yaml'}:8: nodes[b].respawn:") and "restarted as a whole" in msg, msg
    msg = error("nodes:\n  - name: a\n    type: marker_test_pattern\n    process: ../x\n")
    assert msg.startswith(f"{tmp_path / 'g.yaml'}:4: nodes[a].process:") and "not a process name" in msg, msg
    msg = error("nodes:\n  - name: a\n    type: marker_test_pattern\n    process: 3\n")
    assert ":4: nodes[a].process: wants str" in msg, msg
    # what is right is shown: `graph show` names each composed node's process
    (tmp_path / "ok.yaml").write_text("nodes:\n  - {name: a, type: marker_test_pattern, process: p}\n"
                                      "  - {name: b, type: topic_logger, process: p, params: {topics: [markers]}}\n"
                                      "  - {name: c, type: topic_logger, params: {topics: [markers]}}\n")
    shown = to_text(check_graph(load_graph(tmp_path / "ok.yaml"))).splitlines()
    assert "  a (marker_test_pattern) in process p" in shown and "  b (topic_logger) in process p" in shown
    assert "  c (topic_logger)" in shown


# ----- in one process, no launcher: the loop's rules ---------------------------------------------

class Ticker(Node):
    """Publishes N frames at 500 Hz (positions = frame number), then overwrites its own arrays."""

    markers = Output("markers", MarkerFrame)
    echo = Input("echo", NodeStatus)

    def __init__(self, name, params=None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.k = 0
        self.inside = False
        self.reentered = 0
        self.echoes: list[str] = []
        self.pos = np.zeros((4, 3))

    def on_start(self) -> None:
        self.add_timer(0.002, self.tick)

    def tick(self) -> None:
        self.inside = True
        self.k += 1
        self.pos[:] = self.k   # one buffer, reused: what a subscriber got must not change with it
        self.markers.publish(MarkerFrame(frame_number=self.k, positions=self.pos, valid=np.ones(4, bool),
                                         residual=np.zeros(4, np.float32)))
        self.pos[:] = -1.0
        self.inside = False
        if self.k == 50:   # a frame whose shapes disagree: rejected in process as over a socket
            self.markers.publish(MarkerFrame(frame_number=0, positions=self.pos, valid=np.ones(4, bool),
                                             residual=np.zeros(2, np.float32)))

    def on_echo(self, msg: NodeStatus) -> None:
        if self.inside:
            self.reentered += 1
        self.echoes.append(msg.detail)
        if len(self.echoes) >= 100:
            self.request_stop()


class Echo(Node):
    """Keeps every frame it gets and answers each on ``echo`` (a cycle back to its publisher)."""

    markers = Input("markers", MarkerFrame)
    echo = Output("echo", NodeStatus)

    def __init__(self, name, params=None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.kept: list[MarkerFrame] = []
        self.writable = 0

    def on_markers(self, msg: MarkerFrame) -> None:
        self.kept.append(msg)
        self.writable += msg.positions.flags.writeable
        self.echo.publish(NodeStatus(node=self.name, state="running", detail=str(msg.frame_number)))
        if len(self.kept) >= 100:
            self.request_stop()


def test_in_process_delivery_copies_never_reenters_and_rejects_like_a_socket(tmp_path) -> None:
    ep = {n: f"ipc://{tmp_path / (n + '.pub')}" for n in ("t", "e")}
    t = Ticker("t", {}, Wiring(node="t", pub_endpoint=ep["t"], outputs={"markers": {"topic": "markers", "subscribers": 1}},
                               inputs={"echo": {"topic": "echo", "endpoints": [ep["e"]], "senders": ["e"]}}))
    e = Echo("e", {}, Wiring(node="e", pub_endpoint=ep["e"], outputs={"echo": {"topic": "echo", "subscribers": 1}},
                             inputs={"markers": {"topic": "markers", "endpoints": [ep["t"]], "senders": ["t"]}}))
    guard = threading.Timer(30.0, lambda: (t.request_stop(), e.request_stop()))   # never a hung test
    guard.start()
    try:
        assert serve([t, e]) == 0
    finally:
        guard.cancel()
    assert [m.frame_number for m in e.kept] == list(range(1, 101))
    for m in e.kept:   # its own copy: the publisher's later writes into its buffer did not reach it
        np.testing.assert_array_equal(m.positions, np.full((4, 3), float(m.frame_number)))
    assert e.writable == 0   # read-only, as decoded frames are
    stats = e.bound_port("markers").stats
    assert stats.rejected == 1 and stats.edges["t"].gaps == 0
    # the echoes came back in order, none while the ticker was in its own handler
    assert t.reentered == 0 and t.echoes == [str(k) for k in range(1, len(t.echoes) + 1)]
    assert len(t.echoes) >= 99


# ----- the live pipeline composed ----------------------------------------------------------------

@pytest.mark.timing
def test_the_composed_live_pipeline_loses_nothing_and_compiles_nothing(launch_graph, tmp_path) -> None:
    cap = SyntheticActor("kiip_full_body", rate=120.0).capture(0, int(120 * 18))
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    save_model(model, tmp_path / "model.json")
    bag = tmp_path / "live.mcap"
    g = launch_graph(f"""
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 120.0, noise_mm: 1.0, loop: true}}
  - name: calibration
    type: calibration
    params: {{model_file: "{tmp_path / 'model.json'}"}}
  - name: solver
    type: frame_solver
    process: live
  - name: retargeter
    type: retargeter
    process: live
    params: {{source: actor, character: standard_20, foot_planting: true}}
  - name: physics
    type: physics_tracker
    process: live
    params: {{stage: claro_pole}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers, actor_pose, character_pose, physics_state]}}
""")
    g.wait_ready()
    time.sleep(5.0)
    assert g.stop() == 0
    compiled = [line for line in g.lines if "jit: compiled" in line]
    assert not compiled, "kernels compiled while the graph ran:\n" + "\n".join(compiled)
    with BagReader(bag) as r:
        frames = {t: [m.frame_number for _, m in r.decoded(t)] for t in ("markers", "actor_pose", "character_pose")}
        actor = [(e.capture_ns, m) for e, m in r.decoded("actor_pose")]
        characters = [m for _, m in r.decoded("character_pose")]
        last = characters[-1]
        physics = sum(1 for _ in r.decoded("physics_state"))
    assert len(frames["actor_pose"]) >= 200, {t: len(f) for t, f in frames.items()}
    # every solved frame reached the retargeter in process and came out of it, in order; the
    # physics tracker in the same process got the characters
    assert frames["character_pose"] == frames["actor_pose"]
    first = frames["markers"].index(frames["actor_pose"][0])   # (frames before the model came are skipped)
    assert first <= 12 and frames["actor_pose"] == frames["markers"][first:first + len(frames["actor_pose"])]
    assert physics >= 0.5 * len(frames["character_pose"]), physics   # (it skips what it cannot keep up with)
    assert np.isfinite(last.joint_positions).all() and (last.joint_quality >= 1).all()
    # each character frame is the retargeting of its actor frame: the same retargeter run here on
    # the recorded actor frames gives every one (the node writes each frame into one set of buffers
    # and one message: what went out must still be each frame's own)
    rt = build("standard_20", None, source_from_model(model.joint_names, model.joint_parent, model.joint_limbs,
                                                      model.limb_names, model.joint_base),
               RetargetOptions(foot_planting=True)).retargeter
    t0 = actor[0][0]
    for (cap_ns, a), c in zip(actor, characters):
        want = rt.process_actor(a.joint_positions, a.joint_quality, a.limb_orientations, a.limb_quality,
                                (cap_ns - t0) * 1e-9)
        assert c.frame_number == a.frame_number
        for got, ref in ((c.joint_positions, want.joint_positions[0]), (c.local_rotations, want.local_rotations[0]),
                         (c.root_position, want.root_positions[0])):
            assert np.abs(got - ref).max() < 1e-12, c.frame_number
        assert (c.joint_quality == want.joint_quality[0]).all(), c.frame_number
    assert len({c.joint_positions.tobytes() for c in characters}) == len(characters)   # no two frames alike
