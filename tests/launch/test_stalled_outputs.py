"""An output that stops while its node's inputs keep receiving is reported stalled by the launcher.

A node whose diagnostics go on is not stalled as a process, but a user whose solver publishes no
poses while markers arrive wants to know it: here a foreign publisher sends the solver a marker
layout its model does not fit, so the solver refuses it and publishes nothing, while the reader's
markers keep coming. The launcher names the output, then says when it flows again (the real
layout sent back).
"""
from __future__ import annotations

import socket
import time

import pytest
import zmq

from graph_helpers import wait_until
from mocapgraph.bus.diagnostics import DIAGNOSTICS_TOPIC
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.launch.liveness import STEADY_REPORTS
from mocapgraph.messages import MarkerLayout, decode, encode
from mocapgraph.messages.codec import topic_frame

pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stalled_outputs(g) -> dict[str, list[str]]:
    return {n["name"]: n["stalled_outputs"] for n in fetch_manifest(g.master)["nodes"]}


def _wait_for_steady_poses(manifest: dict, reports: int = STEADY_REPORTS + 2, timeout: float = 60.0) -> None:
    """Until the solver's diagnostics showed actor_pose advancing in ``reports`` reports in a row (on
    a loaded machine the first poses can come seconds after ready; a fixed sleep could end before
    the launcher saw the steady flow it watches for)."""
    diag = subscribe(manifest, [DIAGNOSTICS_TOPIC])
    try:
        t_end, last, moving = time.monotonic() + timeout, None, 0
        while moving < reports:
            assert time.monotonic() < t_end, f"actor_pose never flowed steadily ({moving} reports)"
            if not diag.poll(500):
                continue
            env, d = decode(diag.recv_multipart())
            if env.sender != "solver" or "actor_pose" not in d.output_topics:
                continue
            sent = int(d.output_sent[list(d.output_topics).index("actor_pose")])
            moving = moving + 1 if last is not None and sent > last else 0
            last = sent
    finally:
        diag.close(0)


def test_a_solver_that_refuses_its_layout_while_markers_arrive_is_reported(launch_graph) -> None:
    port = _free_port()
    pub = zmq.Context.instance().socket(zmq.XPUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind(f"tcp://127.0.0.1:{port}")
    g = launch_graph(f"""
external:
  - {{topic: marker_layout, type: MarkerLayout, endpoint: "tcp://127.0.0.1:{port}"}}
nodes:
  - name: reader
    type: synthetic_actor
    params: {{rate_hz: 30.0}}
    remap: {{ground_truth_model: skeleton_model}}
  - name: solver
    type: frame_solver
""")
    g.wait_ready(60)
    assert pub.poll(20000) and pub.recv() == b"\x01" + topic_frame("marker_layout"), "the solver subscribes"
    manifest = fetch_manifest(g.master)
    layouts = subscribe(manifest, ["marker_layout"])
    assert layouts.poll(10000), "the reader's latched layout"
    _, real = decode(layouts.recv_multipart())
    _wait_for_steady_poses(manifest)   # the launcher watches an output once it flowed steadily
    assert "stalled" not in g.output, g.output
    wrong = MarkerLayout(name="other_lab", labels=[f"X{i}" for i in range(len(real.labels))],
                         limb_names=list(real.limb_names), marker_limb=real.marker_limb, source="a foreign publisher")
    t0 = time.monotonic()
    pub.send_multipart(encode("marker_layout", wrong, 1, time.time_ns(), "intruder", latched=True))
    line = g.wait_for("node solver output actor_pose stalled", timeout=15)
    took = time.monotonic() - t0
    print(f"reported after {took:.1f} s: {line}")
    assert 3.0 <= took <= 8.0
    assert "while its inputs received" in line and "node reader" not in g.output.split("stalled")[0]
    assert _stalled_outputs(g) == {"reader": [], "solver": ["actor_pose"]}
    assert not any(n["stalled"] for n in fetch_manifest(g.master)["nodes"]), "the process itself talks"
    pub.send_multipart(encode("marker_layout", real, 2, time.time_ns(), "intruder", latched=True))
    g.wait_for("node solver output actor_pose is flowing again", timeout=15)
    wait_until(lambda: _stalled_outputs(g) == {"reader": [], "solver": []}, 10, "cleared", g)
    assert g.output.count("stalled") == 1, g.output
    assert g.stop() == 0
    layouts.close(0)
    pub.close(0)
