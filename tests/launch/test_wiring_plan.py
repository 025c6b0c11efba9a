"""The wiring plan is a pure function of the checked graph: checked here without processes."""
from __future__ import annotations

from pathlib import Path

from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph
from mocapgraph.launch.wiring_plan import plan_wiring

ROOT = Path(__file__).resolve().parents[2]


def test_demo_plan_connects_every_input_to_its_publishers_and_counts_subscribers() -> None:
    graph = check_graph(load_graph(ROOT / "graph_configs" / "demo.yaml"))
    endpoints = {rn.name: f"ipc:///tmp/x/{rn.name}" for rn in graph.nodes}
    plan = plan_wiring(graph, endpoints, "ipc:///tmp/x/control")
    assert set(plan) == {rn.name for rn in graph.nodes}
    # independent reference: walk the resolved nodes' topic maps by hand
    pubs = {}
    for rn in graph.nodes:
        for t in rn.outputs.values():
            pubs.setdefault(t, set()).add(endpoints[rn.name])
    for rn in graph.nodes:
        w = plan[rn.name]
        assert w.pub_endpoint == endpoints[rn.name] and w.control == "ipc:///tmp/x/control"
        for port, topic in rn.inputs.items():
            want = pubs.get(topic, set()) if topic != "diagnostics" else set(endpoints.values())
            assert set(w.inputs[port]["endpoints"]) == want, (rn.name, port)
        for port, topic in rn.outputs.items():
            others = sum(1 for o in graph.nodes if o is not rn for t in o.inputs.values() if t == topic)
            assert w.outputs[port]["subscribers"] == others, (rn.name, port)
    # the solver's pose reaches the viewer: one subscriber expected at least
    solver = next(rn for rn in graph.nodes if "actor_pose" in rn.outputs.values())
    port = next(p for p, t in solver.outputs.items() if t == "actor_pose")
    assert plan[solver.name].outputs[port]["subscribers"] >= 1
