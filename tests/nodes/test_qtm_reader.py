"""The qtm_reader node as a real process against the QTM RT simulator over loopback TCP (and UDP):
values equal the synthetic actor's ground truth, QTM's axes and millimetres undone, occlusions as
NaN with quality 0, QTM going away and coming back, a server that never answers, malformed
packets and lost frames counted. (That the simulator speaks QTM's protocol is checked with
Qualisys's own client in tests/formats/test_qtm_rt.py.)"""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats import qtm_rt as q
from mocapgraph.testing.qtm_server import ActorQTMSource, QTMSimServer, encode_components

pytestmark = pytest.mark.slow

START = 2400


def status(n) -> dict:
    return json.loads(n.messages("reader_status")[-1].data_json)


def free_port(kind=socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def frames_from(n, topic: str, count: int, timeout: float = 15.0):
    return n.wait_for(lambda: n.records(topic) if len(n.records(topic)) >= count else None, timeout,
                      f"{count} messages on {topic}")


def quat_close(a: np.ndarray, b: np.ndarray, atol: float) -> None:
    """Quaternions equal up to sign."""
    d = np.minimum(np.abs(a - b).max(axis=-1), np.abs(a + b).max(axis=-1))
    assert np.nanmax(d) < atol, np.nanmax(d)


@pytest.mark.parametrize("axis_up,transport", [("+Y", "tcp"), ("+Z", "udp")])
def test_values_equal_the_actor_in_world_metres(run_node, axis_up, transport) -> None:
    src = ActorQTMSource("plug_in_gait", 120.0, n_bodies=5, axis_up=axis_up, occlude_every=4)
    srv = QTMSimServer(src, port=0, start_frame=START).start()
    try:
        params = {"port": srv.port, "layout": "plug_in_gait"}
        if transport == "udp":
            params["udp_port"] = free_port(socket.SOCK_DGRAM)
        n = run_node("qtm_reader", params)
        recs = frames_from(n, "markers", 40)
        bodies = frames_from(n, "rigid_bodies", 40)
        skel = frames_from(n, "skeleton_pose", 40)
        strays = frames_from(n, "unlabelled_markers", 40)
        n.wait_for(lambda: status(n)["frames"] >= 40, what="status")
        st = status(n)
    finally:
        srv.stop()
    layout = n.messages("marker_layout")[-1]
    assert layout.labels == src.labels and "up axis " + axis_up in layout.units_note
    assert n.messages("rigid_body_layout")[-1].names == src.body_names
    info = n.messages("skeleton_info")[-1]
    assert info.joint_names == src.limb_names and list(info.joint_parent) == list(src.limb_parent)
    fns = [r.msg.frame_number for r in recs]
    assert np.all(np.diff(fns) == 1) and fns[0] >= START
    cap = src.actor.capture(fns[0], fns[-1] + 1)
    pos = np.array([r.msg.positions for r in recs])
    valid = np.array([r.msg.valid for r in recs])
    occluded = np.array([k % 4 == 0 for k in fns])
    np.testing.assert_allclose(pos[valid], cap.markers[valid], atol=1e-6)        # float32 mm -> m
    assert occluded.any() and (~valid).sum() == occluded.sum()
    assert np.isnan(pos[~valid]).all()                                           # NaN, never 0,0,0
    assert all(np.allclose(r.msg.residual[v], 0.8e-3) for r, v in zip(recs, valid))
    # 6DOF bodies: the limbs' centroids and orientations, back in the world
    b = [r.msg for r in bodies if r.msg.frame_number in set(fns)]
    idx = [fns.index(m.frame_number) for m in b]
    bp = np.array([m.positions for m in b])
    bq = np.array([m.orientations for m in b])
    ok = np.array([m.quality for m in b]) == 2
    np.testing.assert_allclose(bp[ok], cap.limb_centroids[idx][:, :5][ok], atol=1e-6)
    quat_close(bq[ok], cap.limb_quat[idx][:, :5][ok], 1e-5)
    assert (~ok).sum() == sum(1 for m in b if m.frame_number % 4 == 0)
    assert np.isnan(bp[~ok]).all() and np.isnan(bq[~ok]).all()
    assert np.allclose(np.array([m.error for m in b])[ok], 0.5e-3)
    # skeleton: segment orientations are the limbs'; the root segment sits at the root's centroid
    s = [r.msg for r in skel if r.msg.frame_number in set(fns)]
    sidx = [fns.index(m.frame_number) for m in s]
    quat_close(np.array([m.joint_orientations for m in s]), cap.limb_quat[sidx], 1e-5)
    np.testing.assert_allclose(np.array([m.joint_positions[0] for m in s]), cap.limb_centroids[sidx][:, 0], atol=1e-6)
    assert all((m.tracking_state == 2).all() for m in s)
    assert strays[-1].msg.positions.shape == (2, 3)
    assert st["device_gaps"] == 0 and st["bad_packets"] == 0 and st["disconnects"] == 0


def start_simulator(port: int, *extra: str) -> subprocess.Popen:
    """``mocapgraph device simulate qtm`` as its own process; returns once it listens."""
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", "qtm", "--port", str(port),
                             "--bodies", "2", "--start-frame", str(START), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = proc.stdout.readline()
    assert "simulated QTM RT server on tcp 127.0.0.1:" in line, line + proc.stdout.read()
    return proc


@pytest.mark.timing
def test_simulator_killed_and_restarted_reconnects_within_2_s_counted_once(run_node) -> None:
    port = free_port()
    sim = start_simulator(port)
    try:
        n = run_node("qtm_reader", {"port": port})
        frames_from(n, "markers", 20, timeout=30)
        sim.kill()                                   # QTM gone without a word: connection reset, port closed
        sim.wait()
        time.sleep(0.5)
        before = len(n.records("markers"))
        sim = start_simulator(port)                  # back: frame numbers start over
        t_back = time.time_ns()
        recs = n.wait_for(lambda: n.records("markers")[before:] or None, 5.0, "frames again")
        assert (recs[0].receive_ns - t_back) / 1e9 < 2.0
        frames_from(n, "markers", before + 20)
        n.wait_for(lambda: status(n)["frames"] >= before + 20, what="status")
        st = status(n)
    finally:
        sim.kill()
        sim.wait()
    assert n.alive()
    assert st["disconnects"] == 1 and st["device_gaps"] == 0     # the outage is one disconnect, not lost frames
    assert n.logged("lost qtm", "disconnect 1") and not n.logged("Traceback")
    assert st["clock_resyncs"] == 0                # the new connection anchors afresh: no false jump


def test_qtm_restarting_by_itself_and_a_refused_version(run_node) -> None:
    src = ActorQTMSource("plug_in_gait", 120.0, n_bodies=1)
    srv = QTMSimServer(src, port=0, restart_every_s=1.0, restart_down_s=0.3).start()
    try:
        n = run_node("qtm_reader", {"port": srv.port})
        n.wait_for(lambda: n.messages("reader_status") and status(n)["disconnects"] >= 2
                   and n.messages("reader_status")[-1].state == "streaming", 15, "two restarts lived through")
        refused = run_node("qtm_reader", {"port": srv.port, "version": "1.7"}, name="old")
        refused.wait_for(lambda: refused.messages("reader_status") and status(refused)["refusals"] >= 2, 10,
                         "the version refused, and asked again")
    finally:
        srv.stop()
    assert n.logged("QTM is shutting down") and n.alive()
    assert any("Version NOT supported" in m.detail for m in refused.messages("reader_status")) and refused.alive()
    assert not refused.records("markers")


def test_a_server_that_never_answers_is_one_line_and_a_retry(run_node) -> None:
    mute = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    mute.bind(("127.0.0.1", 0))
    mute.listen(8)                                # accepts (kernel backlog), never says a word
    n = run_node("qtm_reader", {"port": mute.getsockname()[1], "answer_timeout_s": 0.5})
    n.wait_for(lambda: n.messages("reader_status") and status(n)["connect_attempts"] >= 3, 10.0, "retries")
    assert n.alive() and n.messages("reader_status")[-1].state == "waiting"
    assert "did not greet" in n.messages("reader_status")[-1].detail
    lines = [ln for ln in n.log().splitlines() if "did not greet" in ln]
    assert 1 <= len(lines) <= 3 and all("\n" not in ln for ln in lines)
    mute.close()
    closed = free_port()
    m = run_node("qtm_reader", {"port": closed}, name="reader2")
    m.wait_for(lambda: m.messages("reader_status") and status(m)["connect_attempts"] >= 2, 10.0, "retries")
    assert m.alive() and m.messages("reader_status")[-1].state == "waiting"


def test_malformed_packets_and_lost_frames_are_counted(run_node) -> None:
    src = ActorQTMSource("plug_in_gait", 240.0, n_bodies=1)
    srv = QTMSimServer(src, port=0, start_frame=START, loss=0.05, bad_every=25, seed=3).start()
    try:
        n = run_node("qtm_reader", {"port": srv.port})
        frames_from(n, "markers", 300)
        n.wait_for(lambda: status(n)["frames"] >= 300, what="status")
        st = status(n)
    finally:
        srv.stop()
    fns = np.array([r.msg.frame_number for r in n.records("markers")][:st["frames"]])
    span = fns[-1] - fns[0] + 1
    lost = [k for k in srv.lost_log if fns[0] < k < fns[-1]]
    bad = [k for k in srv.bad_log if fns[0] < k < fns[-1]]
    assert len(lost) > 3 and len(bad) > 5
    # every frame number not published is a frame QTM skipped or a malformed packet: counted exactly
    assert st["device_gaps"] == span - len(fns) == len(lost) + len(bad)
    assert 0 <= st["bad_packets"] - len(bad) <= 2      # (one before the first, one after the last frame)
    assert n.alive() and st["disconnects"] == 0


def _handshake(conn: socket.socket, src: ActorQTMSource) -> None:
    """Play QTM's side up to StreamFrames (what the simulator does), on a raw socket."""
    conn.sendall(q.encode_string(q.PACKET_COMMAND, q.WELCOME))
    split, seen = q.PacketSplitter(), []
    while not any(t.lower().startswith("streamframes") for t in seen):
        for _t, payload in split.feed(conn.recv(65536)):
            text = q.packet_text(payload)
            seen.append(text)
            if text.lower().startswith("version"):
                conn.sendall(q.encode_string(q.PACKET_COMMAND, "Version set to 1.25"))
            elif text.lower().startswith("getparameters"):
                conn.sendall(q.encode_string(q.PACKET_XML, src.parameters("1.25", ("all",))))


def rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS"))


@pytest.mark.timing  # counts every one of 100 000 datagrams on loopback
def test_100000_malformed_packets_counted_memory_flat_and_a_broken_stream_reconnects(run_node) -> None:
    src = ActorQTMSource("plug_in_gait", 120.0, n_bodies=2)
    good = [q.encode_data(START + i, i * 8333, encode_components(src.frame(START + i), ("3dres",), 120.0))
            for i in range(3)]
    rng = np.random.default_rng(1)
    bad_kinds = [
        q.encode_packet(q.PACKET_DATA, q.DATA_HEADER.pack(0, 1, 1) + q.HEADER.pack(16, q.COMP_3D)
                        + q.COUNT_RATES.pack(0xFFFFFFFF, 0, 0)),                      # lying marker count
        q.encode_packet(q.PACKET_DATA, q.DATA_HEADER.pack(0, 1, 3)),                   # components missing
        q.encode_packet(q.PACKET_DATA, good[0][8:40]),                                 # truncated frame
        q.encode_packet(77, b"\x01\x02"),                                              # unknown packet type
        q.encode_packet(q.PACKET_DATA, rng.integers(0, 256, 60, dtype=np.uint8).tobytes()),
    ]
    blast = b"".join(bad_kinds * 4000)                                                 # 20 000 per round
    lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    lsock.bind(("127.0.0.1", 0))
    lsock.listen(4)
    lsock.settimeout(10)
    n = run_node("qtm_reader", {"port": lsock.getsockname()[1], "layout": "plug_in_gait"})
    conn, _ = lsock.accept()
    _handshake(conn, src)
    conn.sendall(good[0])
    frames_from(n, "markers", 1)
    rss0 = rss_kb(n.proc.pid)
    for r in range(5):
        conn.sendall(blast)
    conn.sendall(good[1])
    frames_from(n, "markers", 2, timeout=60)
    n.wait_for(lambda: status(n)["bad_packets"] >= 100_000, 10, "bad packets counted")
    st = status(n)
    assert st["bad_packets"] == 100_000 and st["frames"] == 2 and st["disconnects"] == 0
    assert rss_kb(n.proc.pid) - rss0 < 20_000, "memory grew by more than 20 MB"
    assert sum("packet skipped" in ln for ln in n.log().splitlines()) < 20          # rate-limited lines
    # a frame whose 6DOF body count is not the parameters': its markers pass, its bodies are skipped
    f = src.frame(START + 9)
    conn.sendall(q.encode_data(START + 9, 9 * 8333, [q.component_3d(f.markers),
                                                     q.component_6d(np.zeros((7, 3), np.float32), np.zeros((7, 9), np.float32))]))
    frames_from(n, "markers", 3)
    n.wait_for(lambda: status(n)["count_mismatches"] == 1, 5, "the body count mismatch counted")
    assert not [r for r in n.records("rigid_bodies") if r.msg.frame_number == START + 9]
    # a header no QTM sends (2 GB): the stream cannot be followed -> dropped, reconnected, counted once
    conn.sendall(q.HEADER.pack(0x7FFFFFF0, q.PACKET_DATA))
    conn2, _ = lsock.accept()
    _handshake(conn2, src)
    conn2.sendall(good[2])
    frames_from(n, "markers", 4)
    n.wait_for(lambda: status(n)["disconnects"] == 1, 5, "one disconnect")
    assert n.logged("lost qtm", "packet header says") and n.alive()
    for c in (conn, conn2, lsock):
        c.close()


def test_no_more_data_is_a_waiting_state_not_a_disconnect(run_node) -> None:
    src = ActorQTMSource("plug_in_gait", 120.0, n_bodies=1)
    srv = QTMSimServer(src, port=0, frames=240).start()      # a 2 s measurement
    try:
        n = run_node("qtm_reader", {"port": srv.port})
        n.wait_for(lambda: n.messages("reader_status") and status(n)["no_more_data"] == 1
                   and n.messages("reader_status")[-1].state == "waiting", 10, "no more data")
        st = status(n)
    finally:
        srv.stop()
    assert st["disconnects"] == 0 and st["frames"] > 0 and n.logged("no measurement running")


def test_the_graph_check_refuses_a_version_qtm_cannot_be_asked_for(tmp_path) -> None:
    from mocapgraph.launch.check import check_graph
    from mocapgraph.launch.graph import load_graph

    for version, ok in (("1.25", True), ("1.7", True), ("two", False), ("1.25; Quit", False)):
        g = tmp_path / "g.yaml"
        g.write_text(f"nodes:\n  - name: reader\n    type: qtm_reader\n    params: {{version: {version!r}}}\n")
        try:
            check_graph(load_graph(g), check_files=False)
            refused = ""
        except Exception as exc:          # the check's one-line error, whatever its class
            refused = str(exc)
        assert (refused == "") == ok and (ok or "not a QTM RT protocol version" in refused), refused


@pytest.mark.timing
def test_capture_stamps_follow_qtm_time_despite_random_send_delays(run_node) -> None:
    src = ActorQTMSource("plug_in_gait", 240.0, n_bodies=1)
    srv = QTMSimServer(src, port=0, start_frame=START, delay_ms=(0.0, 20.0), seed=4).start()
    try:
        # over UDP each datagram's delay is its own (over TCP a held-back frame holds back the next)
        n = run_node("qtm_reader", {"port": srv.port, "udp_port": free_port(socket.SOCK_DGRAM)})
        recs = frames_from(n, "markers", 240 * 4, timeout=30)
        truth = dict(srv.capture_log)
    finally:
        srv.stop()
    # in the order the reader published them (datagrams may overtake each other)
    err_ms = np.array([(r.env.capture_ns - truth[r.msg.frame_number]) / 1e6 for r in recs])
    arrival_ms = np.array([(r.receive_ns - truth[r.msg.frame_number]) / 1e6 for r in recs])
    # Each frame arrives 0-20 ms late, more on a loaded machine. A stamp is the capture time plus
    # about the least delay seen so far (ClockSync's line under the fastest frames; one-way delay
    # below that is invisible to any stamp): never before the capture, never more than 1 ms later
    # than the frame before (the line settles as its windows fill: 0.27 ms seen on a loaded machine;
    # a frame's own 0-20 ms delay never shows), and
    # by the end no later than the least delay this test's own subscriber saw (it receives after
    # the reader). Stamping on arrival, or anchoring on the first frame's delay, fails this.
    assert err_ms.min() > -0.01 and np.diff(err_ms).max() < 1.0, np.percentile(err_ms, [0, 50, 100])
    # (within 0.1 ms: the line's drift estimate from a few seconds of jittered frames may tilt it by
    # some microseconds; 14 us seen)
    assert err_ms[-1] <= arrival_ms.min() + 0.1, (err_ms[-1], arrival_ms.min())
    assert np.percentile(arrival_ms, 90) > 10.0          # the delays were there to be undone
