"""Real graphs of several processes on real sockets: delivery, latching, remaps, includes,
respawn, clean shutdown, no orphans, and garbage on a node's socket."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import zmq

from graph_helpers import (assert_pattern_frame, node_pids, pid_alive, read_jsonl, run_concurrently,
                           wait_until)
from mocapgraph.messages import MarkerFrame, encode
from mocapgraph.messages.codec import topic_frame

pytestmark = pytest.mark.slow  # launched graphs and the tools against them


PIPELINE = """\
args:
  rate: {default: 200.0}
  count: {default: 0}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {rate_hz: "${rate}", n_markers: 6, count: "${count}", missing_every: 5}
    remap: {markers: raw_markers}
"""


@pytest.mark.timing
def test_messages_arrive_intact_typed_and_complete(launch_graph, tmp_path) -> None:
    (tmp_path / "pipeline.yaml").write_text(PIPELINE)
    g = launch_graph(f"""\
include:
  - file: {tmp_path / 'pipeline.yaml'}
    args: {{count: 150}}
nodes:
  - name: logger
    type: topic_logger
    params: {{path: {tmp_path / 'log.jsonl'}, topics: [raw_markers, marker_layout]}}
  - name: logger2
    type: topic_logger
    params: {{path: {tmp_path / 'log2.jsonl'}, topics: [raw_markers]}}
""")
    g.wait_ready()
    wait_until(lambda: "node pattern exited with code 0" in g.output, what="the pattern to finish")
    assert g.stop() == 0
    for name in ("log.jsonl", "log2.jsonl"):
        recs = [r for r in read_jsonl(tmp_path / name) if r["topic"] == "raw_markers"]
        # The start-up handshake means not one of the first frames is lost (slow joiner).
        assert [r["seq"] for r in recs] == list(range(1, 151))
        for r in recs[::17]:
            assert_pattern_frame(r, 6, 200.0, missing_every=5)
    layout = [r for r in read_jsonl(tmp_path / "log.jsonl") if r["topic"] == "marker_layout"]
    assert len(layout) == 1 and layout[0]["msg"]["labels"] == [f"P{i}" for i in range(6)]


@pytest.mark.timing
def test_latched_value_reaches_late_joiners_and_respawn_keeps_the_graph_going(launch_graph, tmp_path) -> None:
    log = tmp_path / "log.jsonl"
    g = launch_graph(f"""\
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 100.0, n_markers: 3}}
  - name: logger
    type: topic_logger
    respawn: true
    respawn_delay: 0.2
    params: {{path: {log}, topics: [markers, marker_layout]}}
""")
    g.wait_ready()
    # A tool started later gets the latched layout at once.
    r = g.cli("topic", "echo", "marker_layout", "-n", "1", "--json", "--timeout", "10")
    assert r.returncode == 0 and json.loads(r.stdout)["msg"]["labels"] == ["P0", "P1", "P2"]
    wait_until(lambda: len(read_jsonl(log)) > 20, what="frames in the log")
    old = node_pids(g)["logger"]
    os.kill(old, signal.SIGKILL)
    g.wait_for("respawning logger")
    wait_until(lambda: node_pids(g)["logger"] not in (old, None), what="a new logger pid")
    # The respawned logger (a late joiner) receives the latched layout again and new frames.
    wait_until(lambda: sum(r["topic"] == "marker_layout" for r in read_jsonl(log)) >= 2, what="layout re-sent")
    n = len(read_jsonl(log))
    wait_until(lambda: len(read_jsonl(log)) > n + 20, what="frames after the respawn")
    assert pid_alive(node_pids(g)["pattern"])
    assert g.stop() == 0


@pytest.fixture(scope="module")
def graphs(launch_module_graph, tmp_path_factory) -> dict:
    """The graphs of the stop, kill, required-death and garbage tests (none judged on time),
    launched together: each spends a second or more starting up, and each test ends its own."""
    tmp = tmp_path_factory.mktemp("running")
    out = {name: launch_module_graph(PIPELINE + f"""\
  - name: logger
    type: topic_logger
    params: {{path: {tmp / (name + '.jsonl')}, topics: [raw_markers]}}
""") for name in ("ctrl_c", "sigkill")}
    out["required"] = launch_module_graph(PIPELINE.replace("count: \"${count}\"", "count: 0") + f"""\
    required: true
  - name: logger
    type: topic_logger
    params: {{path: {tmp / 'required.jsonl'}, topics: [raw_markers]}}
""")
    pub = zmq.Context.instance().socket(zmq.XPUB)
    port = pub.bind_to_random_port("tcp://127.0.0.1")
    log = tmp / "garbage.jsonl"
    out["garbage"] = launch_module_graph(f"""\
external:
  - {{topic: markers, type: MarkerFrame, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [markers]}}
"""), pub, log
    yield out
    pub.close(0)


def running_pattern_and_logger(g) -> tuple:
    g.wait_ready()
    pids = list(node_pids(g).values())
    assert len(pids) == 2 and all(pid_alive(p) for p in pids)
    return g, pids


def test_ctrl_c_leaves_no_process_behind(graphs) -> None:
    g, pids = running_pattern_and_logger(graphs["ctrl_c"])
    assert g.stop() == 0  # SIGINT, as Ctrl-C sends
    assert "stopped in" in g.output
    wait_until(lambda: not any(pid_alive(p) for p in pids), timeout=5, what="nodes to exit")


def test_launcher_killed_with_sigkill_leaves_no_orphan(graphs) -> None:
    g, pids = running_pattern_and_logger(graphs["sigkill"])
    g.proc.kill()
    g.proc.wait()
    wait_until(lambda: not any(pid_alive(p) for p in pids), timeout=5, what="orphans to die")


def test_required_node_death_stops_the_graph_with_nonzero_exit(graphs) -> None:
    g = graphs["required"]
    g.wait_ready()
    os.kill(node_pids(g)["pattern"], signal.SIGKILL)
    g.proc.wait(10)
    assert g.proc.returncode == 1
    assert "required node pattern died" in g.output


def test_garbage_on_a_nodes_socket_is_counted_and_logged(graphs) -> None:
    g, pub, log = graphs["garbage"]
    g.wait_ready()
    assert pub.poll(10000), "the logger never subscribed"
    assert pub.recv() == b"\x01" + topic_frame("markers")
    good = MarkerFrame(frame_number=1, rate_hz=100, positions=np.ones((4, 3)), valid=np.ones(4, bool),
                       residual=np.zeros(4))
    def frames(seq: int) -> list[bytes]:
        return [bytes(f) for f in encode("markers", good, seq, 0, "device")]

    bad = [
        frames(1)[:1] + [frames(1)[1][:9]],                                          # truncated header
        [frames(1)[0], frames(1)[1].replace(b"MarkerFrame", b"MarkerFramX"), *frames(1)[2:]],  # unknown type
        [*frames(2)[:3], frames(2)[3][:-24], *frames(2)[4:]],                         # wrong array size
    ]
    for f in bad:
        pub.send_multipart(f)
    pub.send_multipart(frames(3))
    wait_until(lambda: len(read_jsonl(log)) == 1, what="the good frame")
    assert read_jsonl(log)[0]["seq"] == 3
    wait_until(lambda: g.output.count("rejected frame") >= 3, what="three logged rejects")
    r = g.cli("topic", "echo", "diagnostics", "--json", "-n", "3", "--timeout", "10")
    diag = [json.loads(line)["msg"] for line in r.stdout.splitlines()]
    d = next(d for d in diag if d["node"] == "logger")
    assert sum(d["edge_rejected"]) == 3 and sum(d["edge_gaps"]) == 0
    assert g.proc.poll() is None  # still running
    assert g.stop() == 0


def test_topic_tools_against_a_running_graph(launch_graph, tmp_path) -> None:
    g = launch_graph(PIPELINE)
    g.wait_ready()
    # list, info and echo of a topic nobody publishes are independent: run at once (their
    # interpreters' start-up shares the cores), and before the rate measurement, which runs alone
    mg = [sys.executable, "-m", "mocapgraph", "topic"]
    r_list, r_info, r_none = run_concurrently([mg + ["list"], mg + ["info", "raw_markers"], mg + ["echo", "nonexistent"]],
                                              timeout=90, env=g.env)
    assert set(r_list.stdout.split()) == {"raw_markers", "marker_layout", "diagnostics"}
    r = r_info
    assert "type: MarkerFrame" in r.stdout and "pattern at ipc://" in r.stdout and "positions: float64[N,3]" in r.stdout
    # The reference: the pattern's own sequence numbers over its publish stamps, seen by this test
    # meanwhile (a busy machine makes the pattern skip ticks, so its real rate, not 200 Hz).
    from mocapgraph.bus.manifest import fetch_manifest, subscribe
    from mocapgraph.messages import decode_envelope

    sock = subscribe(fetch_manifest(g.master), ["raw_markers"])
    seen: list[tuple[int, int]] = []
    hz = subprocess.Popen([sys.executable, "-m", "mocapgraph", "topic", "hz", "raw_markers", "--duration", "2.5"],
                          env=g.env, stdout=subprocess.PIPE, text=True)
    while hz.poll() is None:
        if sock.poll(50):
            env = decode_envelope(sock.recv_multipart())
            seen.append((env.seq, env.publish_ns))
    out = hz.stdout.read()
    sock.close(0)
    last = [line for line in out.splitlines() if line.startswith("rate")][-1].split()
    rate, n = float(last[1]), int(last[last.index("window") + 1])
    # hz's figure is the rate of its last `window` messages: it must be the rate (sequence numbers
    # over publish stamps) of some run of that many consecutive messages seen here.
    seq, stamp = np.array(seen, np.int64).T
    k = n - 1
    runs = (seq[k:] - seq[:-k]) / ((stamp[k:] - stamp[:-k]) / 1e9)
    print(f"topic hz: {rate:.2f} Hz over {n}; runs of {n} seen here: {runs.min():.2f}-{runs.max():.2f} Hz")
    assert runs.min() * 0.995 <= rate <= runs.max() * 1.005, out
    assert runs.max() <= 201  # the pattern at (at most) its 200 Hz
    assert "gaps 0" in out.splitlines()[-1]
    assert r_none.returncode == 2 and "no topic 'nonexistent'" in r_none.stderr
    assert g.stop() == 0


def test_tools_without_a_graph_say_so(tmp_path) -> None:
    import subprocess
    import sys
    env = dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp_path / 'none'}")
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "topic", "list"], env=env, capture_output=True,
                       text=True, timeout=20)
    assert r.returncode == 2 and "no running graph answers" in r.stderr and "Traceback" not in r.stderr
