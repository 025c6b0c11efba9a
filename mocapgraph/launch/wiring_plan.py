"""The wiring plan: which endpoints each node binds and connects to, and whom it waits for (pure)."""
from __future__ import annotations

from ..bus.diagnostics import DIAGNOSTICS_TOPIC
from ..bus.protocol import Wiring
from .check import CheckedGraph


def plan_wiring(graph: CheckedGraph, endpoints: dict[str, str], control: str = "") -> dict[str, Wiring]:
    """Every node's Wiring, from the checked graph and each node's publisher endpoint.

    Each input connects to every publisher of its topic (the graph's nodes and its ``external``
    entries); each output waits for as many subscriptions as other nodes' inputs name its topic
    (a node's own inputs on a topic it also publishes are not waited for).
    """
    publishers: dict[str, list[str]] = {}
    for rn in graph.nodes:
        for topic in rn.outputs.values():
            publishers.setdefault(topic, []).append(endpoints[rn.name])
    for ext in graph.spec.external:
        publishers.setdefault(ext.topic, []).append(ext.endpoint)
    publishers[DIAGNOSTICS_TOPIC] = [endpoints[rn.name] for rn in graph.nodes]
    subscribers: dict[str, int] = {}
    for rn in graph.nodes:
        for topic in rn.inputs.values():
            subscribers[topic] = subscribers.get(topic, 0) + 1
    plan = {}
    for rn in graph.nodes:
        own: dict[str, int] = {}
        for topic in rn.inputs.values():
            own[topic] = own.get(topic, 0) + 1
        plan[rn.name] = Wiring(
            node=rn.name,
            pub_endpoint=endpoints[rn.name],
            inputs={p: {"topic": t, "endpoints": publishers.get(t, [])} for p, t in rn.inputs.items()},
            outputs={p: {"topic": t, "subscribers": subscribers.get(t, 0) - own.get(t, 0)}
                     for p, t in rn.outputs.items()},
            control=control,
            diagnostics_subscribers=subscribers.get(DIAGNOSTICS_TOPIC, 0) - min(1, own.get(DIAGNOSTICS_TOPIC, 0)),
        )
    return plan
