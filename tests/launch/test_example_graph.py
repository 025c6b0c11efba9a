"""graph_configs/examples/outlets.yaml passes the graph check (every node type and param known)."""
from __future__ import annotations

from pathlib import Path

from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph

EXAMPLE = Path(__file__).resolve().parents[2] / "graph_configs" / "examples" / "outlets.yaml"


def test_outlets_example_checks():
    spec = load_graph(EXAMPLE)
    check_graph(spec)  # raises GraphError (file:line: key: message) on any fault
    types = {n.type for n in spec.nodes}
    assert {"foxglove_bridge", "lsl_outlet", "osc_outlet", "visualizer"} <= types


def test_vmc_example_checks():
    spec = load_graph(EXAMPLE.with_name("vmc.yaml"))
    check_graph(spec)
    assert {"synthetic_character", "vmc_outlet"} <= {n.type for n in spec.nodes}
