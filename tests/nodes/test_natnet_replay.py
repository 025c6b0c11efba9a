"""The real Motive 2.1 / NatNet 3.0 capture replayed at its own timing (`mocapgraph device replay`,
its own process) to a running natnet_reader: what the reader publishes agrees with OptiTrack's own
SampleClient printout of the same session, frame by frame (frame ids, labelled and unlabelled
marker positions, rigid body pose, error and valid flag, system latency taken off the stamps)."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from tests.natnet_reference import PRINT_TOL, frames_of, natnet_datagrams, parse_sample_client
from tests.nodes.test_natnet_reader import free_udp_port

pytestmark = pytest.mark.slow


@pytest.fixture
def natnet_dir(shared_data):
    d = shared_data / "natnet"
    if not (d / "traffic.pcapng").is_file():
        pytest.skip("../shared/data/natnet is absent")
    return d


def test_replayed_capture_agrees_with_the_sample_client(run_node, natnet_dir, tmp_path) -> None:
    port = free_udp_port()
    # up_axis auto, no device file: Motive's own axes, as the SampleClient prints them
    n = run_node("natnet_reader", {"server": "127.0.0.1", "command_port": port, "up_axis": "auto",
                                   "retry_s": 0.1, "silence_s": 30.0})
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (os.getcwd(), os.environ.get("PYTHONPATH")) if p))
    rep = subprocess.run([sys.executable, "-m", "mocapgraph", "device", "replay", str(natnet_dir / "traffic.pcapng"),
                          "--port", str(port), "--wait", "20"], capture_output=True, text=True, timeout=60, env=env)
    assert rep.returncode == 0, rep.stderr
    assert "sent 518 frames" in rep.stderr
    n.wait_for(lambda: len(n.records("markers")) >= 518, timeout=10, what="518 frames")
    ref = parse_sample_client(natnet_dir / "SampleClient_output.txt")
    decoded = {f.frame_number: f for _, f in frames_of(natnet_datagrams(natnet_dir / "traffic.pcapng"))}
    layout = n.messages("marker_layout")[-1]
    assert layout.labels == [f"RaceQuad:Marker{i}" for i in range(1, 6)]
    assert n.messages("rigid_body_layout")[-1].names == ["RaceQuad"]
    markers = {r.msg.frame_number: r for r in n.records("markers")}
    unlab = {m.frame_number: m for m in n.messages("unlabelled_markers")}
    bodies = {m.frame_number: m for m in n.messages("rigid_bodies")}
    assert sorted(markers) == sorted(decoded)                     # every captured frame, once
    worst = {"labelled": 0.0, "unlabelled": 0.0, "body pos": 0.0, "body quat": 0.0, "error": 0.0}
    excess = []
    compared = 0
    for fid, r in ref.items():
        if fid not in markers:
            continue
        compared += 1
        m = markers[fid].msg
        want = np.array([p for model, _, occl, p in r.labelled if model == 2])
        worst["labelled"] = max(worst["labelled"], float(np.abs(m.positions - want).max()))
        assert m.valid.all()
        loose = np.array(r.other + [p for model, _, _, p in r.labelled if model == 0])
        worst["unlabelled"] = max(worst["unlabelled"], float(np.abs(unlab[fid].positions - loose).max()))
        (rid, err, valid, vals), b = r.bodies[0], bodies[fid]
        assert rid == 2 and valid and b.quality.tolist() == [2]
        worst["body pos"] = max(worst["body pos"], float(np.abs(b.positions[0] - vals[:3]).max()))
        wxyz = np.array([vals[6], *vals[3:6]])
        worst["body quat"] = max(worst["body quat"], float(np.abs(b.orientations[0] - wxyz).max()))
        worst["error"] = max(worst["error"], abs(float(b.error[0]) - err))
        # stamped at arrival minus the system latency the SampleClient printed
        excess.append((markers[fid].receive_ns - markers[fid].env.capture_ns) / 1e6 - r.system_ms)
    n.wait_for(lambda: json.loads(n.messages("reader_status")[-1].data_json)["frames"] == 518, what="the status")
    st = json.loads(n.messages("reader_status")[-1].data_json)
    print(f"\nreplay: {compared} frames compared with the SampleClient; max |difference| "
          + ", ".join(f"{k} {v:.4f}" for k, v in worst.items())
          + f"; stamp minus printed system latency: median {np.median(excess):.2f} ms; status gaps "
            f"{st['gaps']}, rejected {st['rejected_total']}")
    assert compared >= 200
    assert all(v <= PRINT_TOL for v in worst.values())
    assert min(excess) >= -0.006                                  # printed to 2 decimals (ms)
    assert st["rejected_total"] == 0 and st["reconnects"] == 0
    assert st["gaps"] == sum(max(0, b - a - 1) for a, b in zip(sorted(decoded), sorted(decoded)[1:]))
