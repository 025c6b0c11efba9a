"""The NatNet reader node in its own process against a NatNet server on loopback (the simulator's
server, or the real capture replayed): names from the model definitions, values equal to the
source's, NaN for occluded markers, bad packets counted, a new rigid body picked up mid-stream, a
restart logged once, a server that never answers reported in one line."""
from __future__ import annotations

import json
import socket
import threading
import time

import numpy as np
import pytest

from mocapgraph.formats import natnet as nn
from mocapgraph.formats import natnet_encode as ne
from mocapgraph.testing.natnet_server import ActorStream, Faults, NatNetServer, simulate, wait_until_ready

pytestmark = pytest.mark.slow


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status(n) -> dict:
    return json.loads(n.messages("reader_status")[-1].data_json)


def start_sim(**kw) -> tuple[threading.Thread, dict]:
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("sent", simulate(**kw)), daemon=True)
    t.start()
    return t, out


def reader(run_node, port: int, **params):
    p = {"server": "127.0.0.1", "command_port": port, "retry_s": 0.2, "silence_s": 0.5}
    p.update(params)
    return run_node("natnet_reader", p)


@pytest.mark.parametrize("version", [(3, 0), (4, 0), (4, 1), (4, 2)], ids=lambda v: "%d.%d" % v)
def test_reader_publishes_the_simulated_actor(run_node, version) -> None:
    port = free_udp_port()
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=3, dropout_rate_hz=0.3, seed=3)
    n = reader(run_node, port, layout="plug_in_gait")
    t, out = start_sim(stream=stream, version=version, command_port=port, count=90, start_frame=500, wait_s=10.0)
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 90 else None, what="90 frames")
    t.join(5)
    layout = n.messages("marker_layout")[-1]
    assert layout.name == "plug_in_gait" and not layout.unplaced
    assert [r.msg.frame_number for r in recs] == list(range(500, 590))
    truth, bpos, bquat = stream.world(500, 590)
    got = np.array([r.msg.positions for r in recs])
    assert np.array_equal(np.isnan(got), np.isnan(truth)) and np.isnan(truth).any()   # occluded -> NaN
    np.testing.assert_allclose(got, truth, atol=2e-6, equal_nan=True)                     # float32 metres
    assert not np.array([r.msg.valid for r in recs])[np.isnan(truth).any(axis=2)].any()
    bl = n.messages("rigid_body_layout")[-1]
    assert bl.names == stream.body_names and bl.ids.tolist() == [101, 102, 103]
    bodies = n.messages("rigid_bodies")[-90:]
    np.testing.assert_allclose([b.positions for b in bodies], bpos, atol=2e-6)
    q = np.array([b.orientations for b in bodies])
    q *= np.sign(q[..., :1]) * np.sign(bquat[..., :1])
    np.testing.assert_allclose(q, bquat, atol=2e-6)
    assert all((b.quality == 2).all() for b in bodies)
    un = n.messages("unlabelled_markers")[-1]
    assert un.positions.shape == (2, 3)
    n.wait_for(lambda: status(n)["frames"] == 90, what="a status counting every frame")
    st = status(n)
    assert st["gaps"] == 0 and st["rejected_total"] == 0 and st["natnet_version"] == "%d.%d" % version
    assert st["rate_hz"] == 120.0
    cap = np.array([r.env.capture_ns for r in recs])
    arrival = np.array([r.receive_ns for r in recs])
    assert ((arrival - cap) >= 3_000_000).all()    # the reported 3 ms system latency taken off


def test_bad_packets_are_counted_and_skipped(run_node) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=2)
    version = (4, 1)
    server = NatNetServer(ne.server_info(stream.server_info(version)), ne.model_defs(stream.model_defs(), version),
                          command_port=0)
    n = reader(run_node, server.command_port, layout="")
    assert wait_until_ready(server, 10.0)
    frames = [ne.frame(f, version) for f in stream.frames(0, 20)]
    good = frames[0]
    bad = [good[:-30],                                          # truncated (header disagrees)
           good[:2] + (len(good) - 44).to_bytes(2, "little") + good[4:-40],   # truncated fields
           good + b"\0" * 100,                                   # oversized
           ne.frame(nn.decode_frame(good, version), (3, 0)),     # wrong version (3.0 layout)
           b"\x07\x00",                                          # shorter than a header
           bytes(range(256)) * 4]                                 # noise
    for i, f in enumerate(frames):
        server.serve()
        server.send(f)
        if i == 5:
            for b in bad:
                server.send(b)
        time.sleep(0.004)
    n.wait_for(lambda: len(n.records("markers")) >= 20, what="20 frames")
    n.wait_for(lambda: status(n)["rejected_total"] >= 6 and status(n)["frames"] == 20, what="everything counted")
    st = status(n)
    print("\nrejected:", st["rejected"])
    # the 3.0-layout frame read as 4.1 runs out of bytes: "truncated" is what it looks like
    assert st["frames"] == 20 and st["rejected"] == {"truncated": 4, "oversized": 1, "malformed": 1}
    assert n.alive()
    server.close()


def test_server_that_never_answers_gives_one_line_and_retries(run_node) -> None:
    port = free_udp_port()
    n = reader(run_node, port)
    n.wait_for(lambda: n.logged("no answer after"), timeout=5, what="the no-answer line")
    time.sleep(1.0)
    lines = [ln for ln in n.log().splitlines() if "no answer after" in ln]
    assert len(lines) == 1 and n.alive()
    n.wait_for(lambda: status(n)["connect_requests"] >= 8, timeout=5, what="still trying")


def _with_wand(f: nn.Frame) -> nn.Frame:
    """A frame with one more rigid body (id 200) and its three labelled markers."""
    rb = np.zeros(1, nn.RIGID_BODY)
    rb["id"], rb["pos"], rb["quat_xyzw"], rb["error"], rb["params"] = 200, (1, 2, 3), (0, 0, 0, 1), 0.001, 1
    lm = np.zeros(3, nn.LABELLED_MARKER)
    lm["id"] = (200 << 16) | np.arange(1, 4)
    lm["pos"] = np.array([[1.0, 2.0, 3.0], [1.1, 2.0, 3.0], [1.0, 2.1, 3.0]], np.float32)
    lm["params"] = [nn.MARKER_PC_SOLVED, nn.MARKER_OCCLUDED, nn.MARKER_PC_SOLVED]
    f.rigid_bodies = np.concatenate([f.rigid_bodies, rb])
    f.labelled_markers = np.concatenate([f.labelled_markers, lm])
    return f


def test_a_rigid_body_added_mid_stream_is_picked_up_without_restart(run_node) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=2)
    version = (4, 2)
    defs = stream.model_defs()
    server = NatNetServer(ne.server_info(stream.server_info(version)), ne.model_defs(defs, version), command_port=0)
    n = reader(run_node, server.command_port, up_axis="auto", silence_s=5.0)
    assert wait_until_ready(server, 10.0)
    frames = list(stream.frames(0, 40))
    for f in frames[:20]:
        server.serve()
        server.send(ne.frame(f, version))
        time.sleep(0.004)
    n.wait_for(lambda: len(n.records("markers")) >= 20, what="20 frames")
    n_labels = len(n.messages("marker_layout")[-1].labels)
    # Motive: a new rigid body (with its marker set) is created while streaming
    defs.rigid_bodies.append(nn.RigidBodyDef("Wand", 200, -1, np.zeros(3, np.float32)))
    defs.marker_sets["Wand"] = ["W1", "W2", "W3"]
    server.defs_packet = ne.model_defs(defs, version)
    for f in frames[20:]:
        server.serve()
        server.send(ne.frame(_with_wand(f), version))
        time.sleep(0.01)
    n.wait_for(lambda: n.messages("rigid_body_layout")[-1].names[-1:] == ["Wand"], what="the new layout")
    n.wait_for(lambda: n.messages("rigid_bodies")[-1].positions.shape == (3, 3), what="3 bodies")
    last = n.messages("rigid_bodies")[-1]
    assert last.positions[2].tolist() == [1, 2, 3] and last.quality.tolist() == [2, 2, 2]
    m = n.messages("markers")[-1]
    labels = n.messages("marker_layout")[-1].labels
    assert len(labels) == n_labels + 3 and labels[-3:] == ["Wand:W1", "Wand:W2", "Wand:W3"]
    np.testing.assert_allclose(m.positions[-3], [1, 2, 3], atol=1e-6)
    assert np.isnan(m.positions[-2]).all() and not m.valid[-2]            # occluded: NaN, never 0,0,0
    n.wait_for(lambda: status(n)["model_updates"] == 1, what="the update counted")
    st = status(n)
    assert st["reconnects"] == 0 and st["unknown_id_frames"] >= 1
    assert server.requests[nn.NAT_REQUEST_MODELDEF] == 2               # asked once more, not per frame
    server.close()


@pytest.mark.timing
def test_restart_is_one_logged_reconnect_within_2_s_and_loss_is_counted_exactly(run_node) -> None:
    port = free_udp_port()
    stream = ActorStream("plug_in_gait", rate_hz=240.0, n_bodies=1)
    n = reader(run_node, port)
    faults = Faults(loss=0.05, restart_after=300, restart_gap_s=1.5, seed=11)
    t, out = start_sim(stream=stream, version=(4, 1), command_port=port, count=600, faults=faults, wait_s=10.0)
    t.join(20)
    assert not t.is_alive()
    n.wait_for(lambda: status(n)["frames"] == out["sent"], what="a status counting every frame")
    recs = n.records("markers")
    numbers = [r.msg.frame_number for r in recs]
    cut = next(i for i in range(1, len(numbers)) if numbers[i] < numbers[i - 1])
    states = [r for r in n.records("reader_status") if r.msg.state == "reconnecting"]
    assert len(states) >= 1
    delay = (states[0].receive_ns - recs[cut - 1].receive_ns) / 1e9
    st = status(n)
    sent = set(numbers)
    # the injected drops of each run that fall between frames the reader saw are what it can count
    d = faults.dropped
    split = next((i for i in range(1, len(d)) if d[i] < d[i - 1]), len(d))
    runs = [(d[:split], numbers[:cut]), (d[split:], numbers[cut:])]
    expected_gaps = sum(sum(seen[0] < x < seen[-1] for x in drops) for drops, seen in runs)
    print(f"\nrestart: reconnect state {delay:.2f} s after the last frame; dropped {len(faults.dropped)} of 600, "
          f"gaps counted {st['gaps']}, reconnects {st['reconnects']}")
    assert 0.4 < delay < 2.0
    # the simulator's end is a silence too (a second reconnect 0.5 s after the last frame): judge the
    # restart by the last status published while frames still flowed
    during = [r for r in n.records("reader_status") if r.receive_ns < recs[-1].receive_ns + 200_000_000]
    assert json.loads(during[-1].msg.data_json)["reconnects"] == 1 and n.logged("reconnecting (reconnect 1)")
    assert len(numbers) == out["sent"] and out["sent"] + len(faults.dropped) == 600 and sent
    assert st["gaps"] == expected_gaps and len(faults.dropped) > 10


def test_multicast_frames_on_loopback(run_node) -> None:
    port, data_port = free_udp_port(), free_udp_port()
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1)
    n = reader(run_node, port, multicast_group="239.255.42.99", data_port=data_port, local_address="127.0.0.1")
    n.wait_for(lambda: n.messages("reader_status") and n.messages("reader_status")[-1].state == "connecting",
               what="sockets open")
    t, out = start_sim(stream=stream, version=(4, 0), command_port=port, count=40, wait_s=10.0,
                       multicast_group="239.255.42.99", data_port=data_port)
    t.join(10)
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 40 else None, what="40 frames")
    assert [r.msg.frame_number for r in recs] == list(range(40))
    # multicast: the simulator knows no unicast client, the frames came through the group
    truth = stream.world(0, 40)[0]
    got = np.array([r.msg.positions for r in recs])
    np.testing.assert_allclose(got, truth, atol=2e-6, equal_nan=True)
    n.wait_for(lambda: status(n)["frames"] == 40, what="status")
    assert status(n)["out_of_order"] == 0


def test_numbering_that_starts_over_is_one_reconnect_and_discovery_finds_the_server(run_node) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1)
    version = (3, 0)
    server = NatNetServer(ne.server_info(stream.server_info(version)), ne.model_defs(stream.model_defs(), version),
                          command_port=0)
    # no server address: a discovery packet (sent here to loopback instead of a subnet's broadcast)
    n = reader(run_node, server.command_port, server="", discovery_address="127.0.0.1", silence_s=5.0)
    assert wait_until_ready(server, 10.0) and server.requests[14] >= 1
    for f in list(stream.frames(1000, 20)) + list(stream.frames(0, 20)):   # Motive restarted its numbering
        server.serve()
        server.send(ne.frame(f, version))
        time.sleep(0.004)
    n.wait_for(lambda: len(n.records("markers")) >= 40, what="40 frames")
    n.wait_for(lambda: status(n)["frames"] == 40, what="status")
    st = status(n)
    assert st["reconnects"] == 1 and st["restarts"] == 1 and st["gaps"] == 0 and st["out_of_order"] == 0
    assert n.logged("frame numbers started over (0 after 1019)") and n.logged("discovered a server at 127.0.0.1")
    server.close()


def _rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))


@pytest.mark.timing  # counts every one of 100 000 datagrams on loopback
def test_100000_bad_packets_counted_with_memory_flat(run_node) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1)
    version = (4, 1)
    server = NatNetServer(ne.server_info(stream.server_info(version)), ne.model_defs(stream.model_defs(), version),
                          command_port=0)
    n = reader(run_node, server.command_port, silence_s=30.0)
    assert wait_until_ready(server, 10.0)
    client = next(iter(server.clients))
    good = ne.frame(next(stream.frames(0, 1)), version)
    rng = np.random.default_rng(1)
    bad = [good[:-50], good + b"\0" * 64, ne.frame(nn.decode_frame(good, version), (3, 0)), b"\x07\x00\xff",
           good[:2] + (len(good) - 104).to_bytes(2, "little") + good[4:-100]]
    bad += [rng.integers(0, 256, int(rng.integers(4, 300)), dtype=np.uint8).tobytes() for _ in range(20)]
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = rss0 = 0
    while sent < 100_000:
        for k in range(1000):
            tx.sendto(bad[(sent + k) % len(bad)], client)
        sent += 1000
        if sent == 20_000:
            n.wait_for(lambda: status(n)["packets"] >= 19_000, what="the first 20 000")
            rss0 = _rss_kb(n.proc.pid)
        time.sleep(0.03)
    tx.close()
    seen: list[int] = []

    def settled() -> bool:  # the count stopped moving: everything that arrived is handled
        seen.append(status(n)["packets"])
        time.sleep(0.6)
        return len(seen) > 2 and seen[-1] == seen[-3]

    n.wait_for(settled, timeout=30, what="the reader to catch up")
    st = status(n)
    assert st["packets"] >= 80_000                              # the rest: dropped by the kernel, not us
    grew = _rss_kb(n.proc.pid) - rss0
    print(f"\n{sent} bad packets sent, {st['packets']} received, rejected {st['rejected']}; RSS grew {grew} kB "
          f"from 20 000 to the end")
    # every packet that arrived was refused and counted (besides server info, definitions, frame rate)
    assert n.alive() and st["frames"] == 0 and st["rejected_total"] == st["packets"] - 3
    assert grew < 2048
    assert not n.records("markers")
    lines = [ln for ln in n.log().splitlines() if "packet skipped" in ln]
    assert len(lines) < 20                                      # rate-limited: a line per 5 s at most
    server.close()


def test_a_natnet_2_server_is_refused_in_one_line_and_its_frames_counted(run_node) -> None:
    stream = ActorStream("plug_in_gait", rate_hz=120.0, n_bodies=1)
    info = stream.server_info((4, 1))
    old = nn.ServerInfo("Motive", (1, 10, 0, 0), (2, 10, 0, 0), info.clock_hz, info.data_port)
    server = NatNetServer(ne.server_info(old), ne.model_defs(stream.model_defs(), (4, 1)), command_port=0)
    n = reader(run_node, server.command_port, silence_s=5.0)
    end = time.monotonic() + 10
    while not server.clients and time.monotonic() < end:
        server.serve()
        time.sleep(0.005)
    for f in stream.frames(0, 10):
        server.send(ne.frame(f, (4, 1)))
        time.sleep(0.004)
    n.wait_for(lambda: status(n)["rejected"].get("wrong_version") == 10, what="10 frames refused")
    assert n.logged("streams NatNet 2.10; this reader reads 3.0 and later") and not n.records("markers")
    assert len([ln for ln in n.log().splitlines() if "streams NatNet 2.10" in ln]) == 1
    server.close()
