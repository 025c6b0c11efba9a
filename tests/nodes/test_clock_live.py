"""A UDP reader's capture stamps against the device simulator's true capture times, with the
simulator's clock 100 ppm fast and every frame 0-20 ms late on the link; the clock's figures as a
bag records them (the reader's diagnostics)."""
from __future__ import annotations

import json
import socket

import numpy as np
import pytest

from graph_helpers import wait_until
from mocapgraph.bag.reader import BagReader
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.messages import decode
from mocapgraph.testing.device_simulator import SimulatedDevice, run_udp

pytestmark = pytest.mark.timing   # (slow too: conftest marks what starts a graph)

RATE = 240.0
SECONDS = 8.0
START = 100

GRAPH = """
nodes:
  - name: reader
    type: udp_reader
    params: {{port: {port}, device: example_udp_bridge, layout: plug_in_gait, allow_from: 127.0.0.1}}
  - name: rec
    type: bag_recorder
    params: {{path: "{bag}", topics: [markers, diagnostics, reader_status]}}
"""


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_stamps_within_1ms_of_true_capture_with_20ms_delay_and_100ppm_drift(launch_graph, tmp_path) -> None:
    port, bag = free_udp_port(), tmp_path / "clock.mcap"
    g = launch_graph(GRAPH.format(port=port, bag=bag))
    g.wait_ready()
    sim = SimulatedDevice("plug_in_gait", "example_udp_bridge", rate_hz=RATE, seed=7, start_frame=START,
                          drift_ppm=100.0, delay_ms=20.0)
    n = int(RATE * SECONDS)
    watch = subscribe(fetch_manifest(g.master), ["reader_status", "diagnostics"])
    assert run_udp(sim, "127.0.0.1", port, count=n) == n
    # the reader's status once it has every frame, then its next diagnostics (into the bag too)
    seen = {"all": False, "diag_after": False}

    def settled() -> bool:
        while watch.poll(0):
            env, msg = decode(watch.recv_multipart())
            if env.topic == "reader_status" and json.loads(msg.data_json)["clock"]["samples"] == n:
                seen["all"] = True
            elif env.topic == "diagnostics" and env.sender == "reader" and seen["all"]:
                seen["diag_after"] = True
        return seen["diag_after"]

    wait_until(settled, 20, "the reader's diagnostics after the last frame", g)
    watch.close(0)
    assert g.stop() == 0
    with BagReader(bag) as r:
        frames = [(msg.frame_number, env.capture_ns) for env, msg in r.decoded("markers")]
        pub = np.array([env.publish_ns for env, msg in r.decoded("markers")])
        diags = [msg for _, msg in r.decoded("diagnostics") if msg.node == "reader"]
        status = json.loads([msg for _, msg in r.decoded("reader_status")][-1].data_json)
    k = np.array([f for f, _ in frames]) - START
    cap = np.array([c for _, c in frames], np.int64)
    assert sorted(k.tolist()) == list(range(n))      # every frame once; overtaken ones are not gaps
    assert status["device_gaps"] == 0 and status["reordered"] > 100 and status["clock_resyncs"] == 0
    true = sim.capture_ns(k)
    err_ms = (cap - true) / 1e6
    t = (true - true.min()) / 1e9
    # The fastest path the machine gave from the simulator to the reader's publishing, over the 2 s
    # before each frame: no estimate from one-way timing can tell it from the clock offset (an idle
    # machine has it near 0.3 ms, a loaded one at several ms), so the 1 ms bound is judged above it.
    # (Measured at load 4-5 on the 2 cores: error 0.3-0.7 ms; at load 7-11: 0.3-3.2 ms, the fastest
    # path 0.8-2.7 ms. A first-frame offset is off by that frame's delay, 0-20 ms, plus 0.8 ms drift.)
    path_ms = (pub - true) / 1e6
    order = np.argsort(t)
    floor_ms = np.empty_like(path_ms)
    for i in order:
        floor_ms[i] = path_ms[(t > t[i] - 2.0) & (t <= t[i])].min()
    late = t >= 2.0
    print(f"error after 2 s: max {err_ms[late].max():.3f} ms, median {np.median(err_ms[late]):.3f} ms, "
          f"min {err_ms[late].min():.3f} ms; fastest path median {np.median(floor_ms[late]):.3f} ms; "
          f"first 2 s: max {err_ms[~late].max():.3f} ms")
    assert err_ms[late].min() > -1.0                                  # never earlier than the truth
    assert np.all(err_ms[late] < floor_ms[late] + 1.0)
    d = diags[-1]
    assert d.clock_names == [f"udp:127.0.0.1:{port}"] and d.clock_resets.tolist() == [0]
    # drift from 6-8 s of window minima: off by about the fastest path's wander over that span
    wander_ppm = (floor_ms[late].max() - floor_ms[late].min()) * 1e3 / 6.0
    print(f"recorded: drift {d.clock_drift_ppm[0]:.1f} ppm (the path wandered {wander_ppm:.0f} ppm's worth), "
          f"jitter {d.clock_jitter_ms[0]:.2f} ms")
    assert d.clock_drift_ppm[0] == pytest.approx(100.0, abs=30.0 + 2 * wander_ppm)
    assert d.clock_jitter_ms[0] > 0.8 * 20 / np.sqrt(12)     # std of U(0, 20 ms) at least, plus the machine's
