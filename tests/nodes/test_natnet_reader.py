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


@pytest.mark.parametrize("version", [(3, 0), (4, 1)])
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
    n.wait_for(lambda: status(n)["rejected_total"] >= 6, what="rejections counted")
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
    assert status(n)["connect_requests"] >= 5          # still trying
