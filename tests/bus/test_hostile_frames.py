"""Hostile frames on a running graph: junk under fresh sender names, a forged sequence number.

The graph takes its markers from an `external:` endpoint that this test binds, as a foreign
publisher would; the real reader publishes on the same topic. The solver must stay bounded in
memory, keep publishing actor_pose, and report the hostile frames on its diagnostics.
"""
from __future__ import annotations

import socket
import time

import numpy as np
import pytest
import zmq

from graph_helpers import node_pids, wait_until
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.messages import MarkerFrame, decode
from mocapgraph.messages.codec import HEADER_AT, encode, header_stream

RATE_HZ = 30.0  # low enough that a loaded 2-core machine leaves the solver time for the junk
N_JUNK = 50_000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


class PoseCounter:
    """Counts actor_pose arrivals and the longest silence between two of them (s)."""

    def __init__(self, sock: zmq.Socket) -> None:
        self.sock = sock
        self.times: list[float] = []

    def drain(self, for_s: float = 0.0) -> None:
        t_end = time.monotonic() + for_s
        while True:
            wait = max(0, int((t_end - time.monotonic()) * 1000))
            if not self.sock.poll(wait):
                if time.monotonic() >= t_end:
                    return
                continue
            while True:
                try:
                    self.sock.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                self.times.append(time.monotonic())

    def since(self, t0: float) -> list[float]:
        return [t for t in self.times if t >= t0]


def _solver_diagnostics(diag_sock: zmq.Socket, timeout: float = 5.0):
    """The solver's newest diagnostics, published after this call (older queued ones are skipped)."""
    while diag_sock.poll(0):
        diag_sock.recv_multipart()
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if diag_sock.poll(200):
            env, msg = decode(diag_sock.recv_multipart())
            if msg.node == "solver":
                return msg
    raise AssertionError("no diagnostics from the solver")


@pytest.fixture(scope="module")
def hostile_graph(launch_module_graph):
    """(graph, the foreign publisher bound to its external markers endpoint): the synthetic actor
    (its exact model latched as skeleton_model) and a solver, launched once for both tests; the
    second floods the reader's subscriptions, which the first test's junk to the solver never reaches."""
    port = _free_port()
    pub = zmq.Context.instance().socket(zmq.PUB)
    pub.setsockopt(zmq.SNDHWM, 0)
    pub.bind(f"tcp://127.0.0.1:{port}")
    g = launch_module_graph(f"""
external:
  - {{topic: markers, type: MarkerFrame, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: reader
    type: synthetic_actor
    params: {{rate_hz: {RATE_HZ}}}
    remap: {{ground_truth_model: skeleton_model}}
  - name: solver
    type: frame_solver
""")
    g.wait_ready(60)
    yield g, pub
    pub.close(0)


def test_junk_senders_and_forged_sequence_leave_the_stream_running(hostile_graph) -> None:
    g, pub = hostile_graph
    assert g.proc.poll() is None, g.output
    manifest = fetch_manifest(g.master)
    poses = PoseCounter(subscribe(manifest, ["actor_pose"]))
    diag = subscribe(manifest, ["diagnostics"])
    wait_until(lambda: poses.drain(0.2) or len(poses.times) > 20, 30, "actor_pose flowing", g)
    solver_pid = node_pids(g)["solver"]
    poses.drain(1.0)
    rss0 = _rss_mb(solver_pid)

    # 50 000 valid-looking frames, each under a sender name never seen before
    junk = MarkerFrame(frame_number=0, rate_hz=RATE_HZ, positions=np.zeros((3, 3)), valid=np.ones(3, bool),
                       residual=np.zeros(3, np.float32))
    template = [bytes(f) for f in encode("markers", junk, 1, time.time_ns(), "junk-000000")]
    head = template[1][:-len(b"000000")]
    t_flood = time.monotonic()
    for i in range(N_JUNK):
        pub.send_multipart([template[0], head + b"%06d" % i, *template[2:]])
        if i % 1000 == 999:
            poses.drain(0.005)

    def unexpected_count() -> int:
        d = _solver_diagnostics(diag)
        return next((d.edge_rejected[i] for i, (t, s) in enumerate(zip(d.edge_topics, d.edge_senders))
                     if t == "markers" and s == "(unexpected)"), 0)

    # every junk frame reaches the solver (no publisher limit, TCP back-pressure): wait for them all
    deadline = time.monotonic() + 60
    while unexpected_count() < N_JUNK - 8 and time.monotonic() < deadline:
        poses.drain(0.5)
    flood_s = time.monotonic() - t_flood
    rss1 = _rss_mb(solver_pid)
    got = poses.since(t_flood)
    d = _solver_diagnostics(diag)
    marker_edges = [i for i, t in enumerate(d.edge_topics) if t == "markers"]
    senders = [d.edge_senders[i] for i in marker_edges]
    print(f"flood {N_JUNK} frames taken in {flood_s:.1f} s: solver RSS {rss0:.1f} -> {rss1:.1f} MB, "
          f"actor_pose {len(got) / flood_s:.1f} Hz, longest silence {np.diff(got).max():.3f} s, "
          f"edges on markers: {senders}")
    assert unexpected_count() >= N_JUNK - 8  # all counted (the first few may take the free edges)
    assert rss1 - rss0 <= 20.0
    assert len(got) / flood_s >= 0.6 * RATE_HZ
    assert len(marker_edges) <= 12, senders  # bounded: the reader, a few free edges, one 'unexpected'
    assert g.output.count("senders the wiring does not name") < 30  # logged, rate-limited

    # one forged frame claiming the real reader's name with sequence 2**63
    n_before = len(poses.times)
    pub.send_multipart(encode("markers", junk, 1 << 63, time.time_ns(), "reader"))
    poses.drain(2.0)
    assert len(poses.times) - n_before >= 0.5 * RATE_HZ * 2.0, "the stream stopped after a forged frame"
    d = _solver_diagnostics(diag)
    i = next(i for i, (t, s) in enumerate(zip(d.edge_topics, d.edge_senders)) if t == "markers" and s == "reader")
    assert d.edge_gaps[i] < 1000 and d.edge_anomalies[i] >= 1


def _frame_numbers(sock: zmq.Socket, for_s: float, sender: str) -> list[int]:
    """Frame numbers of the messages from ``sender`` arriving on ``sock`` within ``for_s`` seconds."""
    out = []
    t_end = time.monotonic() + for_s
    while time.monotonic() < t_end or sock.poll(0):
        if sock.poll(50):
            env, msg = decode(sock.recv_multipart())
            if env.sender == sender:
                out.append(msg.frame_number)
    return out


def test_a_forged_frame_4000_ahead_of_the_real_stream_costs_it_one_frame(hostile_graph) -> None:
    g, pub = hostile_graph
    assert g.proc.poll() is None, g.output
    manifest = fetch_manifest(g.master)
    markers = subscribe(manifest, ["markers"])
    poses = subscribe(manifest, ["actor_pose"])
    wait_until(lambda: poses.poll(200) and markers.poll(200), 30, "markers and actor_pose flowing", g)

    def missing(for_s: float) -> tuple[list[int], list[int]]:
        """Frames the reader sent in ``for_s`` s that got no pose (the last 10 may be in flight)."""
        while poses.poll(0):
            poses.recv_multipart()
        while markers.poll(0):
            markers.recv_multipart()
        got = _frame_numbers(poses, for_s, "solver")
        sent = _frame_numbers(markers, 0.0, "reader")   # what queued on the markers socket meanwhile
        sent = [f for f in sent if f >= min(got, default=0)][:-10]
        assert len(sent) >= 0.5 * RATE_HZ * for_s, sent
        return sorted(set(sent) - set(got)), got

    lost_before, _ = missing(3.0)
    # the real reader's newest frame: its stream id and number, as anyone on the bus can read them
    while True:
        frames = markers.recv_multipart()
        env, _ = decode(frames)
        if env.sender == "reader":
            break
    head = bytearray(frames[1])
    forged = MarkerFrame(frame_number=-4000, rate_hz=RATE_HZ, positions=np.zeros((3, 3)), valid=np.ones(3, bool),
                         residual=np.zeros(3, np.float32))
    out = [bytes(f) for f in encode("markers", forged, env.seq + 4000, time.time_ns(), "reader")]
    fhead = bytearray(out[1])
    fhead[HEADER_AT["stream"]:HEADER_AT["stream"] + 4] = head[HEADER_AT["stream"]:HEADER_AT["stream"] + 4]
    assert header_stream(fhead) == header_stream(head) != 0
    pub.send_multipart([out[0], bytes(fhead), *out[2:]])
    lost_after, got = missing(4.0)
    print(f"frames without a pose: {lost_before} in 3 s before a forged frame at real+4000, "
          f"{lost_after} in 4 s after it ({len(got)} poses)")
    assert len(lost_after) <= 1 + len(lost_before), "the forged frame silenced the solver"
    assert len(got) >= 0.5 * RATE_HZ * 4.0
    markers.close(0)
    poses.close(0)


def test_subscription_flood_neither_multiplies_latched_values_nor_grows_the_publisher(hostile_graph) -> None:
    g, _ = hostile_graph  # the reader's latched model is on skeleton_model there
    assert g.proc.poll() is None, g.output
    manifest = fetch_manifest(g.master)
    endpoint = manifest["topics"]["skeleton_model"]["publishers"][0]["endpoint"]
    observer = subscribe(manifest, ["skeleton_model"])
    assert observer.poll(10_000), "a late joiner gets the latched model"
    observer.recv_multipart()
    pid = node_pids(g)["reader"]
    rss0 = _rss_mb(pid)
    ctx = zmq.Context.instance()
    flood = ctx.socket(zmq.XSUB)  # raw subscription messages, as a hostile peer sends them
    flood.setsockopt(zmq.RCVHWM, 1)
    flood.setsockopt(zmq.SNDHWM, 0)
    flood.connect(endpoint)
    time.sleep(0.3)
    t0 = time.monotonic()
    for i in range(N_JUNK):
        flood.send(b"\x01skeleton_model\0")  # the same topic, again and again
        if i % 2 == 0:
            flood.send(b"\x01junk-%06d" % i)  # and topics nobody publishes
    copies = 0
    t_end = time.monotonic() + 3.0
    while time.monotonic() < t_end:
        if observer.poll(100):
            observer.recv_multipart()
            copies += 1
    elapsed = time.monotonic() - t0
    rss1 = _rss_mb(pid)
    print(f"subscription flood: {copies} copies of the latched model in {elapsed:.1f} s to a subscriber that "
          f"asked once; publisher RSS {rss0:.1f} -> {rss1:.1f} MB")
    # at most one resend per 50 ms per topic, however many subscribe
    assert copies <= elapsed / 0.05 + 5
    assert rss1 - rss0 <= 20.0
    late = subscribe(manifest, ["skeleton_model"])
    assert late.poll(5000), "a late joiner still gets the latched value after the flood"
    flood.close(0)
