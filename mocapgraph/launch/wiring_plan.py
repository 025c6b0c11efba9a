"""The wiring plan: which endpoints each node binds and connects to, and whom it waits for (pure)."""
from __future__ import annotations

from ..bus.diagnostics import DIAGNOSTICS_TOPIC
from ..bus.protocol import Wiring
from ..bus.stats import ANY_SENDER
from .check import CheckedGraph


def plan_wiring(graph: CheckedGraph, endpoints: dict[str, str], control: str = "") -> dict[str, Wiring]:
    """Every node's Wiring, from the checked graph and each node's publisher endpoint.

    Each input connects to every publisher of its topic (the graph's nodes and its ``external``
    entries); each output waits for as many subscriptions as other nodes' inputs name its topic
    (a node's own inputs on a topic it also publishes are not waited for). Each input also gets
    the names of the nodes that send on its topic, so frames under any other sender name are
    rejected; an external publisher, or a node that relays recorded sender names (a bag
    player), adds ANY_SENDER (a few unnamed senders allowed).
    """
    publishers: dict[str, list[str]] = {}
    senders: dict[str, list[str]] = {}
    for rn in graph.nodes:
        for topic in rn.outputs.values():
            publishers.setdefault(topic, []).append(endpoints[rn.name])
            senders.setdefault(topic, []).append(ANY_SENDER if getattr(rn.cls, "relays_senders", False) else rn.name)
    for ext in graph.spec.external:
        publishers.setdefault(ext.topic, []).append(ext.endpoint)
        senders.setdefault(ext.topic, []).append(ANY_SENDER)
    publishers[DIAGNOSTICS_TOPIC] = [endpoints[rn.name] for rn in graph.nodes]
    senders[DIAGNOSTICS_TOPIC] = [rn.name for rn in graph.nodes]
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
            inputs={p: {"topic": t, "endpoints": publishers.get(t, []), "senders": sorted(set(senders.get(t, [])))}
                    for p, t in rn.inputs.items()},
            outputs={p: {"topic": t, "subscribers": subscribers.get(t, 0) - own.get(t, 0)}
                     for p, t in rn.outputs.items()},
            control=control,
            curve=({"key": graph.spec.security.key, "authorized": graph.spec.security.authorized}
                   if graph.spec.security.curve else {}),
            diagnostics_subscribers=subscribers.get(DIAGNOSTICS_TOPIC, 0) - min(1, own.get(DIAGNOSTICS_TOPIC, 0)),
        )
    return plan
