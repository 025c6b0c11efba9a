"""Two machines' clocks: launchers in two network namespaces measure each other's clock offset over
the link (launch.machine_clock), and a node's latency from the other machine comes out true.

The namespaces share one kernel clock, so the "render" machine's launcher and nodes read theirs
37 ms ahead (MOCAPGRAPH_TEST_CLOCK_OFFSET_NS, read by messages.clock_sync.wall_ns: tests only).
Needs root and network namespaces; skipped cleanly elsewhere (the fixture's rule).
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from graph_helpers import read_jsonl, wait_until
from mocapgraph.bus.manifest import fetch_manifest
from test_netns_two_machines import A_IP, B_IP, two_namespaces  # noqa: F401 (the fixture)

pytestmark = [pytest.mark.slow, pytest.mark.timing]  # two network namespaces; an offset judged to 0.5 ms

OFFSET_MS = 37.0


def test_an_injected_37ms_offset_is_measured_within_half_a_millisecond(two_namespaces, tmp_path: Path) -> None:
    ns_a, ns_b, _ = two_namespaces
    markers, diags = tmp_path / "markers.jsonl", tmp_path / "diag.jsonl"
    graph = tmp_path / "split.yaml"
    graph.write_text(f"""
security: {{insecure: true}}
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: 50.0}}
    machine: capture
    host: {A_IP}
    port: 47011
  - name: logger
    type: topic_logger
    params: {{path: {markers}, topics: [markers]}}
    machine: render
    host: {B_IP}
    port: 47012
  - name: watcher
    type: topic_logger
    params: {{path: {diags}, topics: [diagnostics]}}
    machine: render
    host: {B_IP}
    port: 47013
""")
    masters = {m: f"ipc://{tmp_path / ('m-' + m)}" for m in ("capture", "render")}
    procs = {}
    try:
        for ns, machine, offset in ((ns_b, "render", OFFSET_MS), (ns_a, "capture", 0.0)):
            env = dict(os.environ, PYTHONUNBUFFERED="1", MOCAPGRAPH_MASTER=masters[machine],
                       MOCAPGRAPH_TEST_CLOCK_OFFSET_NS=str(int(offset * 1e6)))
            procs[machine] = subprocess.Popen(["ip", "netns", "exec", ns, sys.executable, "-m", "mocapgraph", "launch",
                                               str(graph), "--machine", machine], env=env, stdout=subprocess.PIPE,
                                              stderr=subprocess.STDOUT, text=True)

        def clocks(machine: str, peer: str) -> dict | None:
            try:
                c = fetch_manifest(masters[machine], timeout_s=1.0).get("clocks", {}).get(peer)
            except Exception:   # not up yet
                return None
            return c if c and c["samples"] >= 20 else None

        seen_from_capture = wait_until(lambda: clocks("capture", "render"), 60, "capture's view of render's clock")
        seen_from_render = wait_until(lambda: clocks("render", "capture"), 30, "render's view of capture's clock")
        print(f"render's clock seen from capture: {seen_from_capture['offset_ns'] / 1e6:+.3f} ms "
              f"(round trip {seen_from_capture['delay_ms']:.3f} ms); capture's from render: "
              f"{seen_from_render['offset_ns'] / 1e6:+.3f} ms")
        assert abs(seen_from_capture["offset_ns"] / 1e6 - OFFSET_MS) < 0.5
        assert abs(seen_from_render["offset_ns"] / 1e6 + OFFSET_MS) < 0.5

        # the logger on render takes markers from capture: its latency is true once the launcher told
        # it capture's clock (uncorrected it would read 37 ms more), and its Diagnostics name that clock
        def told() -> dict | None:
            for rec in reversed(read_jsonl(diags, "diagnostics")):
                d = rec["msg"]
                if d["node"] == "logger" and "machine:capture" in d["clock_names"] and "markers" in d["edge_topics"]:
                    return d
            return None

        d = wait_until(told, 30, "the logger's diagnostics with capture's clock")
        lat = d["edge_latency_ms"][d["edge_topics"].index("markers")]
        off = d["clock_offset_ms"][d["clock_names"].index("machine:capture")]
        print(f"logger: markers latency {lat:.3f} ms; capture's clock {off:+.3f} ms behind")
        assert abs(off - OFFSET_MS) < 0.5
        assert 0.0 < lat < 20.0
        assert len(read_jsonl(markers, "markers")) > 10
    finally:
        outs = {}
        for m, p in procs.items():
            p.send_signal(2)
            try:
                outs[m] = p.communicate(timeout=30)[0]
            except subprocess.TimeoutExpired:
                p.kill()
                outs[m] = p.communicate()[0]
        for m, out in outs.items():
            print(f"--- {m}\n{out}")
    said = re.findall(r"clock of machine render: ([+-][0-9.]+) ms", outs["capture"])
    assert said and abs(float(said[0]) - OFFSET_MS) < 0.5, outs["capture"]      # the console says it too
