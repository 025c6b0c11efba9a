"""The UDP reader on a real socket and the LSL reader against a real LSL outlet in another
process (`mocapgraph device simulate lsl`), including a stream with the wrong channel count."""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from mocapgraph.formats.wire_protocol import encode_binary
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.testing.device_simulator import SimulatedDevice, run_udp


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def status(n) -> dict:
    return json.loads(n.messages("reader_status")[-1].data_json)


@pytest.mark.timing
def test_udp_datagrams_through_a_device_file_and_bad_datagrams_counted(run_node) -> None:
    port = free_udp_port()
    n = run_node("udp_reader", {"port": port, "device": "example_udp_bridge", "layout": "plug_in_gait"})
    n.wait_for(lambda: n.messages("reader_status") and n.messages("reader_status")[-1].state == "streaming",
               what="listening")
    sim = SimulatedDevice("plug_in_gait", "example_udp_bridge", rate_hz=120.0, seed=2, start_frame=3000)
    frames = list(sim.frames(30))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i, f in enumerate(frames):
            data = encode_binary(f.frame, f.t_us, f.positions)
            if i == 5:
                s.sendto(data[:-7], ("127.0.0.1", port))                 # truncated datagram
            if i == 6:
                s.sendto(bytes(np.random.default_rng(0).integers(0, 256, 500, dtype=np.uint8)),
                         ("127.0.0.1", port))                            # noise
            if i == 7:
                bad = bytearray(data)
                bad[30] ^= 0xFF
                s.sendto(bytes(bad), ("127.0.0.1", port))                # corrupted: CRC fails
            s.sendto(data, ("127.0.0.1", port))
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 30 else None,
                      what="30 frames")
    assert [r.msg.frame_number for r in recs] == list(range(3000, 3030))
    # The bridge is turned 90 deg and set 1.5 m back: the reader undoes it exactly (float32 mm).
    want = SyntheticActor("plug_in_gait", rate=120.0, seed=2).capture(3000, 3030).markers
    np.testing.assert_allclose(np.array([r.msg.positions for r in recs]), want, atol=2e-6)
    n.wait_for(lambda: status(n)["crc_errors"] >= 1, what="the corrupted datagram counted")
    st = status(n)
    assert st["datagrams"] == 33 and st["frames"] == 30 and st["rejected_bytes"] >= 500
    time.sleep(0.05)
    assert len(n.records("markers")) == 30                               # nothing invented from garbage


@pytest.mark.timing
def test_udp_reader_fed_by_the_device_simulator_in_real_time(run_node) -> None:
    port = free_udp_port()
    n = run_node("udp_reader", {"port": port, "device": "example_udp_bridge", "layout": "plug_in_gait",
                                "allow_from": "127.0.0.1"})
    n.wait_for(lambda: n.messages("reader_status") and n.messages("reader_status")[-1].state == "streaming",
               what="listening")
    sim = SimulatedDevice("plug_in_gait", "example_udp_bridge", rate_hz=240.0, seed=5, start_frame=500)
    t_send = time.time_ns()
    assert run_udp(sim, "127.0.0.1", port, count=120) == 120             # half a second, paced
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 120 else None,
                      what="120 frames")
    want = SyntheticActor("plug_in_gait", rate=240.0, seed=5).capture(500, 620).markers
    np.testing.assert_allclose(np.array([r.msg.positions for r in recs]), want, atol=2e-6)
    assert all(r.msg.rate_hz == 120.0 for r in recs)                     # the device file's nominal rate
    # Mapped onto our clock by the frames that came fastest (messages.clock_sync), judged by events
    # of this very run rather than a latency figure (a busy machine delays the reader by 100 ms and
    # more): frame k left no earlier than t_send + k/240 s and no stamp is later than its frame
    # was published; the stamps never go back.
    cap = np.array([r.env.capture_ns for r in recs])
    sent_earliest = t_send + np.round(np.arange(120) * 1e6 / 240) * 1000     # device stamps are µs
    assert np.all(cap >= sent_earliest - 1000)
    assert np.all(cap <= [r.env.publish_ns for r in recs])
    assert np.all(np.diff(cap) >= 0)
    clock = n.wait_for(lambda: next((c for c in [json.loads(n.messages("reader_status")[-1].data_json)["clock"]]
                                     if c["samples"] == 120), None), what="the clock in reader_status")
    assert clock["resets"] == 0 and 0 < clock["jitter_ms"] < 100
    diag = n.diagnostics()
    assert diag.clock_names == [f"udp:127.0.0.1:{port}"] and diag.clock_resets.tolist() == [0]
    dev0_ns = round(500 * 1e6 / 240) * 1000
    assert t_send - dev0_ns <= diag.clock_offset_ms[0] * 1e6 <= recs[0].env.publish_ns - dev0_ns


def test_udp_port_in_use_is_a_clear_error(run_node) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        n = run_node("udp_reader", {"port": s.getsockname()[1]})
        assert n.wait_exit(10) == 1
        detail = n.messages("reader_status")[-1].detail
        assert "cannot listen" in detail and str(s.getsockname()[1]) in detail


def simulate_lsl(name: str, layout: str, device: str, count: int, rate: float = 100.0) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", "lsl", "--name", name,
                             "--layout", layout, "--device", device, "--rate", str(rate), "--count", str(count),
                             "--seed", "4", "--noise-mm", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


@pytest.mark.timing
def test_lsl_wrong_channel_count_is_refused_then_the_right_stream_is_read(run_node) -> None:
    name = f"mg_test_{int(time.time() * 1000) % 10**8}"
    # A stream of one_arm markers (12 x 3 channels) where the device file expects 39 markers.
    wrong = simulate_lsl(name, "one_arm", "", count=300)
    try:
        n = run_node("lsl_reader", {"stream_name": name, "device": "example_lsl_mocap", "layout": "plug_in_gait",
                                    "resolve_s": 0.1})
        n.wait_for(lambda: any("36 channels" in s.detail for s in n.messages("reader_status")), timeout=90,
                   what="the wrong stream refused")
        assert n.logged("36 channels, expected 117", level="ERROR")
        assert n.alive() and n.messages("markers") == []
        right = simulate_lsl(name, "plug_in_gait", "example_lsl_mocap", count=400)
        try:
            recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 40 else None,
                              timeout=90, what="frames from the right stream")
            diag = n.diagnostics()                                   # while the stream is up
        finally:
            right.kill()
            right.wait()
    finally:
        wrong.kill()
        wrong.wait()
    lay = n.messages("marker_layout")[0]
    actor = SyntheticActor("plug_in_gait", rate=100.0, seed=4, options=CaptureOptions(noise_mm=0.5))
    assert lay.labels == list(actor.skeleton.marker_labels) and "mm -> m" in lay.units_note
    # LSL has no frame counter: find which simulated frame each sample is by its content
    # (unique: every frame has its own noise).
    first = recs[0].msg.positions
    ref = actor.capture(0, 400).markers
    k0 = int(np.argmin(np.nanmax(np.abs(ref - first), axis=(1, 2))))
    got = np.array([r.msg.positions for r in recs[:30]])
    np.testing.assert_allclose(got, ref[k0:k0 + 30], atol=2e-6)          # float32 mm, Y-up -> world
    # LSL stamps (pushed at 100 Hz in real time) mapped to our clock: spacing ~10 ms, close to now.
    cap = np.array([r.env.capture_ns for r in recs])
    assert np.median(np.diff(cap)) == pytest.approx(1e7, rel=0.2)
    lag = np.array([r.env.publish_ns - r.env.capture_ns for r in recs]) / 1e6
    assert np.median(lag) < 50 and (lag > -5).all()
    assert len(status(n)["refused_streams"]) == 1
    # LSL's own clock correction is the followed clock: same host, so none (0 ms)
    assert diag.clock_names == [f"lsl:name='{name}' and type='Mocap'"] and diag.clock_offset_ms.tolist() == [0.0]
