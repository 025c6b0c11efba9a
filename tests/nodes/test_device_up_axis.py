"""``up_axis`` on the device readers (serial, UDP, LSL): a Y-up device whose file sets no up axis
is read right by saying ``up_axis: y``, fed by the real device simulator; a device file whose own
``to_world.up`` disagrees is refused in one line."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

from mocapgraph.formats.device_file import DeviceConfigError, device_or_default, load_device_config
from mocapgraph.formats.wire_protocol import encode_binary, encode_text
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.testing.device_simulator import SimulatedDevice, open_pty


@pytest.fixture
def devices(tmp_path):
    """Device files: the simulator's true Y-up frame, the same device without axes, a Z-up one."""
    files = {
        "yup": "name: yup_bridge\nrate_hz: 120\nto_world:\n  up: \"+Y\"\n  translation_m: [0.5, 0, 0]\n",
        "plain": "name: yup_bridge\nrate_hz: 120\nto_world:\n  translation_m: [0.5, 0, 0]\n",
        "zup": "name: zup_bridge\nrate_hz: 120\nto_world:\n  forward: \"+X\"\n  up: \"+Z\"\n",
        "fwd_y": "name: odd\nto_world:\n  forward: \"+Y\"\n",
    }
    out = {}
    for key, text in files.items():
        (tmp_path / f"{key}.yaml").write_text(text)
        out[key] = str(tmp_path / f"{key}.yaml")
    return out


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def streaming(n) -> bool:
    msgs = n.messages("reader_status")
    return bool(msgs) and msgs[-1].state == "streaming"


def test_up_axis_stands_in_for_the_device_files_up_and_refuses_a_second_answer(devices) -> None:
    truth = load_device_config(devices["yup"])
    dev = device_or_default(devices["plain"], "y")
    np.testing.assert_array_equal(dev.rotation, truth.rotation)      # +Y up, +X forward -> world
    np.testing.assert_array_equal(dev.translation, [0.5, 0, 0])      # the file's translation kept
    assert "from the reader's up_axis" in dev.describe()
    assert device_or_default(devices["plain"], "auto").is_identity is False  # translation only
    np.testing.assert_array_equal(device_or_default(devices["plain"], "auto").rotation, np.eye(3))
    assert device_or_default(devices["yup"], "+y") is not None      # the same answer twice is fine
    with pytest.raises(DeviceConfigError) as exc:
        device_or_default(devices["zup"], "y")
    msg = str(exc.value)
    assert msg.startswith(f"{devices['zup']}:5: to_world.up:") and "'+Z'" in msg and "\n" not in msg
    with pytest.raises(DeviceConfigError, match="to_world.forward.*not perpendicular"):
        device_or_default(devices["fwd_y"], "y")
    # no device file at all: the reader's up_axis alone turns the device frame
    p = np.array([[0.1, 0.2, 0.3]])
    np.testing.assert_allclose(device_or_default("", "y").points_to_world(p), [[0.1, -0.3, 0.2]])


def test_udp_reader_with_up_axis_reads_a_y_up_device_right(run_node, devices) -> None:
    port = free_udp_port()
    n = run_node("udp_reader", {"port": port, "device": devices["plain"], "up_axis": "y",
                                "layout": "plug_in_gait"})
    n.wait_for(lambda: streaming(n), what="listening")
    sim = SimulatedDevice("plug_in_gait", devices["yup"], rate_hz=120.0, seed=3, start_frame=600)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for f in sim.frames(20):
            s.sendto(encode_binary(f.frame, f.t_us, f.positions), ("127.0.0.1", port))
            time.sleep(0.001)
    recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 20 else None, what="20 frames")
    want = SyntheticActor("plug_in_gait", rate=120.0, seed=3).capture(600, 620).markers
    np.testing.assert_allclose(np.array([r.msg.positions for r in recs]), want, atol=2e-6)
    assert "up axis +Y from the reader's up_axis" in n.messages("marker_layout")[0].units_note


def test_serial_reader_with_up_axis_reads_a_y_up_device_right(run_node, devices) -> None:
    master, slave, path = open_pty()
    try:
        n = run_node("serial_reader", {"port": path, "protocol": "text", "device": devices["plain"],
                                       "up_axis": "+Y", "layout": "plug_in_gait"})
        n.wait_for(lambda: streaming(n), what="port open")
        sim = SimulatedDevice("plug_in_gait", devices["yup"], rate_hz=120.0, seed=1, start_frame=100)
        os.write(master, b"".join(encode_text(f.frame, f.t_us, f.positions) for f in sim.frames(20)))
        recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 20 else None,
                          what="20 frames")
    finally:
        os.close(master)
        os.close(slave)
    want = SyntheticActor("plug_in_gait", rate=120.0, seed=1).capture(100, 120).markers
    np.testing.assert_allclose(np.array([r.msg.positions for r in recs]), want, atol=1e-6)


def test_a_device_file_with_another_up_is_refused_in_one_line(run_node, devices) -> None:
    n = run_node("udp_reader", {"port": free_udp_port(), "device": devices["zup"], "up_axis": "y"})
    assert n.wait_exit(10) == 1
    detail = n.messages("reader_status")[-1].detail
    assert f"{devices['zup']}:5: to_world.up" in detail and "up_axis" in detail and "\n" not in detail


def test_lsl_reader_with_up_axis_reads_the_simulated_y_up_outlet(run_node, devices) -> None:
    name = f"mg_up_{os.getpid()}_{int(time.time() * 1000) % 10**6}"
    sim = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", "lsl", "--name", name,
                            "--layout", "one_arm", "--device", devices["yup"], "--rate", "100",
                            "--count", "1000", "--seed", "6", "--noise-mm", "0.5"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        n = run_node("lsl_reader", {"stream_name": name, "device": devices["plain"], "up_axis": "y",
                                    "layout": "one_arm", "resolve_s": 0.1})
        # a generous wait: the simulator is a fresh process importing pylsl on a loaded machine
        recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= 20 else None,
                          timeout=25, what="frames from the outlet")
        n.stop()   # the inlet closes while its outlet still exists: a clean exit, no liblsl retrying
    finally:
        sim.kill()
        sim.wait()
    ref = SyntheticActor("one_arm", rate=100.0, seed=6, options=CaptureOptions(noise_mm=0.5)).capture(0, 1000).markers
    first = recs[0].msg.positions
    k0 = int(np.argmin(np.nanmax(np.abs(ref - first), axis=(1, 2))))  # LSL has no frame counter
    got = np.array([r.msg.positions for r in recs[:20]])
    np.testing.assert_allclose(got, ref[k0:k0 + 20], atol=2e-6)
