"""``graph check`` loads only registered node types, mocapgraph modules and files the graph names
(issue 30, item 11): a ``module:Class`` type used to import any module on the path, running its
import-time code on a mere check. The real CLI checks graphs naming a module whose import leaves
a mark, a standard-library module, and a node file next to the graph (which loads and launches).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

from graph_helpers import CommandsRunning, read_jsonl, run_concurrently, wait_until

NODE_FILE = '''
from pathlib import Path
from mocapgraph.bus import Node, Output, Param
from mocapgraph.messages import NodeStatus

Path(__file__).with_name("imported.mark").write_text("imported")


class Beacon(Node):
    """Publishes one status a second."""

    summary = "test beacon"
    out = Output("beacon", NodeStatus, "one status a second")
    text = Param("hello", "what to say")

    def on_start(self):
        self.add_timer(0.1, lambda: self.out.publish(NodeStatus(node=self.name, state=self.text)))
'''


def _check_command(graph: Path) -> list[str]:
    return [sys.executable, "-m", "mocapgraph", "graph", "check", str(graph)]


def test_a_module_type_outside_mocapgraph_is_refused_without_being_imported(tmp_path):
    lib = tmp_path / "site"
    lib.mkdir()
    (lib / "lab_plugin.py").write_text(NODE_FILE)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(lib), os.environ.get("PYTHONPATH", "")]))
    graphs = []
    for i, type_name in enumerate(("lab_plugin:Beacon", "os:system", "antigravity:X")):
        graphs.append(graph := tmp_path / f"g{i}.yaml")
        graph.write_text(f"nodes:\n  - name: n\n    type: {type_name}\n")
    # three independent checks at once (each interpreter start costs a core's half second)
    for graph, r in zip(graphs, run_concurrently([_check_command(g) for g in graphs], timeout=120, env=env,
                                                 cwd=tmp_path)):
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert r.returncode != 0 and len(lines) == 1, (r.stdout, r.stderr)
        assert f"{graph}:3: nodes[n].type" in lines[0] and "only registered types" in lines[0], lines[0]
    assert not (lib / "imported.mark").exists()     # its import-time code never ran


def test_a_node_file_the_graph_names_loads_and_runs(launch_graph, tmp_path):
    (tmp_path / "nodes").mkdir()
    (tmp_path / "nodes" / "beacon.py").write_text(NODE_FILE)
    log = tmp_path / "log.jsonl"
    text = f"""\
nodes:
  - name: b
    type: nodes/beacon.py:Beacon
    params: {{text: hi}}
  - name: logger
    type: topic_logger
    params: {{path: {log}, topics: [beacon]}}
"""
    graph = tmp_path / "graph.yaml"
    graph.write_text(text)
    missing = tmp_path / "g_missing.yaml"
    missing.write_text("nodes:\n  - name: n\n    type: nodes/nope.py:Beacon\n")
    # the two checks at once, while the graph starts (independent processes)
    checks = CommandsRunning([_check_command(graph), _check_command(missing)], cwd=tmp_path)
    g = launch_graph(graph)
    g.wait_ready()
    wait_until(lambda: read_jsonl(log, "beacon"), timeout=20, what="the beacon", graph=g)
    assert read_jsonl(log, "beacon")[0]["msg"]["state"] == "hi"
    assert g.stop() == 0
    r, r_missing = checks.results(timeout=120)
    assert r.returncode == 0, r.stderr
    r = r_missing
    assert r.returncode != 0 and "no file" in r.stderr and "g_missing.yaml:3" in r.stderr, r.stderr
