"""The serial reader on real pseudo-terminal pairs: the node opens the slave path with pyserial,
the test writes the device's bytes to the master. Text and binary protocols, partial lines,
garbage, random bytes, a port absent at start, and a port that vanishes mid-stream."""
from __future__ import annotations

import json
import os
import tty

import numpy as np
import pytest

from mocapgraph.formats.wire_protocol import encode_binary, encode_text
from mocapgraph.kinematics.synthetic.actor import SyntheticActor
from mocapgraph.testing.device_simulator import SimulatedDevice


pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh


def pty_pair() -> tuple[int, int, str]:
    master, slave = os.openpty()
    tty.setraw(slave)  # a device line: no echo, no line editing
    return master, slave, os.ttyname(slave)


def write_in_pieces(fd: int, data: bytes, piece: int) -> None:
    for k in range(0, len(data), piece):
        os.write(fd, data[k:k + piece])


def status(n) -> dict:
    return json.loads(n.messages("reader_status")[-1].data_json)


def streaming(n) -> bool:
    msgs = n.messages("reader_status")
    return bool(msgs) and msgs[-1].state == "streaming"


@pytest.fixture
def pty():
    opened: list[int] = []

    def make() -> tuple[int, int, str]:
        m, s, path = pty_pair()
        opened.extend([m, s])
        return m, s, path

    yield make
    for fd in opened:
        try:
            os.close(fd)
        except OSError:
            pass


def test_text_protocol_in_pieces_with_garbage_gives_world_positions(run_node, pty) -> None:
    master, _, path = pty()
    n = run_node("serial_reader", {"port": path, "protocol": "text", "device": "example_serial_bridge",
                                   "layout": "plug_in_gait"})
    n.wait_for(lambda: streaming(n), what="port open")
    sim = SimulatedDevice("plug_in_gait", "example_serial_bridge", rate_hz=120.0, seed=1, start_frame=2400)
    frames = list(sim.frames(40))
    # The device frame really is the example bridge's: Y up, Z forward, channels alphabetical.
    actor = SyntheticActor("plug_in_gait", rate=120.0, seed=1)
    world = actor.capture(2400, 2440).markers                       # [40, 39, 3], layout order
    labels = list(actor.skeleton.marker_labels)
    k = sorted(labels).index("LASI")
    np.testing.assert_allclose(frames[0].positions[k], world[0, labels.index("LASI")][[1, 2, 0]], atol=1e-12)

    stream = b"# bridge v1.2 booting\n"
    for i, f in enumerate(frames):
        stream += encode_text(f.frame, f.t_us, f.positions)
        if i == 10:
            stream += b"\x00\xff\xfegarbage line\n"
        if i == 20:
            stream += b"F 99 99 3 1 2 3 4 5 6 7 8 9\n"                 # a frame of 3 markers: wrong count
        if i == 30:
            stream += encode_text(f.frame, f.t_us, f.positions)[:-40] + b"\n"   # cut short: bad count
    write_in_pieces(master, stream, 97)                                 # lines split anywhere
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 40 else None,
                      what="40 frames")
    assert [r.msg.frame_number for r in recs] == list(range(2400, 2440))
    got = np.array([r.msg.positions for r in recs])
    np.testing.assert_allclose(got, world, atol=1e-6)                   # text carries 1 µm (0.001 mm)
    assert all(r.msg.rate_hz == 120.0 for r in recs)
    lay = n.messages("marker_layout")[0]
    assert lay.labels == labels and lay.unplaced == []
    assert "example_serial_bridge" in lay.units_note
    # Device time stamps mapped to our clock by the frames that came fastest (messages.clock_sync):
    # 0.33 s of frames written at once cannot have been captured after they arrived, so no stamp
    # lies after its frame was published (a first-frame offset put the last one 0.32 s ahead of
    # it), the stamps never go back, and none spreads wider than the device's own spacing.
    cap = np.array([r.env.capture_ns for r in recs])
    assert np.all(cap <= [r.env.publish_ns for r in recs])
    dev_step = np.diff([f.t_us * 1000 for f in frames])
    assert np.all(np.diff(cap) >= 0) and np.all(np.diff(cap) <= dev_step)
    assert abs(cap[-1] - recs[-1].env.publish_ns) < 50e6
    n.wait_for(lambda: status(n)["count_mismatches"] >= 1 and status(n)["rejected_frames"] >= 2,
               what="rejects in the status")
    st = status(n)
    assert st["frames"] == 40 and st["rejected_bytes"] > 0
    assert n.logged("bad frame") and n.logged("has 3 markers")
    diag = n.diagnostics()
    i = diag.edge_topics.index(f"serial:{path}")
    assert diag.edge_received[i] == 40 and diag.edge_rejected[i] >= 3


def test_binary_protocol_survives_random_bytes(run_node, pty) -> None:
    master, _, path = pty()
    n = run_node("serial_reader", {"port": path, "protocol": "binary", "layout": "one_arm"})
    n.wait_for(lambda: streaming(n), what="port open")
    sim = SimulatedDevice("one_arm", "", rate_hz=200.0, seed=3)       # channels in layout order, world frame
    frames = list(sim.frames(60))
    rng = np.random.default_rng(5)
    stream = b"".join(encode_binary(f.frame, f.t_us, f.positions) for f in frames[:20])
    stream += rng.integers(0, 256, 20000, dtype=np.uint8).tobytes()
    stream += b"".join(encode_binary(f.frame, f.t_us, f.positions) for f in frames[20:])
    write_in_pieces(master, stream, 1000)
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 60 else None,
                      what="60 frames")
    assert [r.msg.frame_number for r in recs] == list(range(60))      # every real frame, nothing invented
    want = SyntheticActor("one_arm", rate=200.0, seed=3).capture(0, 60).markers
    np.testing.assert_allclose(np.array([r.msg.positions for r in recs]), want, atol=5e-7)  # float32 mm
    n.wait_for(lambda: status(n)["rejected_bytes"] >= 19000, what="random bytes counted")
    assert status(n)["rate_hz"] == pytest.approx(200.0, rel=1e-3)    # measured from device stamps


def test_port_absent_at_start_then_vanishing_midstream_is_reopened(run_node, pty, tmp_path) -> None:
    link = tmp_path / "ttyMOCAP"                                        # like /dev/serial/by-id/...
    n = run_node("serial_reader", {"port": str(link), "protocol": "text", "reopen_s": 0.02,
                                   "reopen_max_s": 0.1})
    n.wait_for(lambda: n.messages("reader_status") and n.messages("reader_status")[-1].state == "waiting",
               what="waiting for the absent port")
    sim = SimulatedDevice("one_arm", "", rate_hz=100.0)
    frames = list(sim.frames(30))
    m1, s1, p1 = pty()
    os.symlink(p1, link)                                                # the device is plugged in
    n.wait_for(lambda: streaming(n), what="port opened once present")
    os.write(m1, b"".join(encode_text(f.frame, f.t_us, f.positions) for f in frames[:10]))
    n.wait_for(lambda: len(n.messages("markers")) >= 10, what="first frames")
    os.write(m1, encode_text(frames[10].frame, frames[10].t_us, frames[10].positions)[:25])  # half a line
    os.close(m1)
    os.close(s1)                                                        # ... and the cable is pulled
    n.wait_for(lambda: n.messages("reader_status")[-1].state == "reconnecting", what="reconnecting state")
    n.wait_for(lambda: status(n)["reopen_attempts"] >= 3, what="reopen attempts")
    assert n.alive()
    m2, _, p2 = pty()
    link.unlink()
    os.symlink(p2, link)                                                # plugged in again
    n.wait_for(lambda: streaming(n), what="port reopened")
    os.write(m2, b"".join(encode_text(f.frame, f.t_us, f.positions) for f in frames[11:]))
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 29 else None,
                      what="frames after reconnecting")
    assert [r.msg.frame_number for r in recs] == list(range(10)) + list(range(11, 30))
    st = status(n)
    assert st["disconnects"] == 1 and st["clock_resyncs"] == 0      # re-anchored on the first new frame
    assert n.logged("lost", str(link))
    assert n.messages("marker_layout")[0].labels == [f"M{i}" for i in range(frames[0].positions.shape[0])]
