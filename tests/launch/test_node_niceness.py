"""A node's `nice:` is its process's niceness (a best-effort node yields the cores); what cannot work is a graph error."""
from __future__ import annotations

import os


from graph_helpers import graph_error, node_pids
from mocapgraph.cli.graph_cmds import to_text
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph


def test_a_launched_node_runs_at_its_niceness_and_the_others_at_the_launchers(launch_graph) -> None:
    g = launch_graph("""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {rate_hz: 50.0, n_markers: 4}
  - name: viewerlike
    type: topic_logger
    nice: 7
    params: {topics: [markers]}
  - name: a
    type: topic_logger
    process: both
    nice: 3
    params: {topics: [markers]}
  - name: b
    type: topic_logger
    process: both
    nice: 3
    params: {topics: [markers]}
""")
    g.wait_ready()
    pids = node_pids(g)
    base = os.getpriority(os.PRIO_PROCESS, 0)
    assert os.getpriority(os.PRIO_PROCESS, pids["pattern"]) == base
    assert os.getpriority(os.PRIO_PROCESS, pids["viewerlike"]) == min(base + 7, 19)
    assert pids["a"] == pids["b"] and os.getpriority(os.PRIO_PROCESS, pids["a"]) == min(base + 3, 19)
    assert g.stop() == 0


def test_a_niceness_that_cannot_work_is_a_graph_error(tmp_path) -> None:
    def error(text: str) -> str:
        return graph_error(tmp_path / "g.yaml", text)

    for bad, what in (("-5", "wants a niceness in 0..19"), ("20", "wants a niceness in 0..19"),
                      ("high", "wants int"), ("2.5", "wants int"), ("true", "wants int")):
        msg = error(f"nodes:\n  - name: a\n    type: marker_test_pattern\n    nice: {bad}\n")
        assert msg.startswith(f"{tmp_path / 'g.yaml'}:4: nodes[a].nice:") and what in msg, msg
    msg = error("""\
nodes:
  - {name: a, type: marker_test_pattern, process: p}
  - {name: b, type: topic_logger, process: p, nice: 5, params: {topics: [markers]}}
""")
    assert msg.startswith(f"{tmp_path / 'g.yaml'}:3: nodes[b].nice:") and "one scheduling priority" in msg, msg
    (tmp_path / "ok.yaml").write_text("nodes:\n  - {name: a, type: marker_test_pattern, nice: 10}\n")
    assert "  a (marker_test_pattern), nice 10" in to_text(check_graph(load_graph(tmp_path / "ok.yaml"))).splitlines()
