"""Several nodes in one OS process: one shared event loop, and messages between them without ZeroMQ.

A launch graph puts nodes in one process with ``process: NAME`` (`mocapgraph.launch.graph`); the
runtime then builds them all and calls `serve`. Each node keeps its own XPUB socket, endpoint,
diagnostics and launcher link, so the rest of the graph sees the same nodes as before; only an
input whose publisher lives in the same process is fed in process (`Node.link_local`): no
serialisation of the hop's wake-ups through ZeroMQ's I/O threads, the same checks, statistics
and decoding. What they share is the process: one node stuck in a handler holds up the others,
and a crash (a segfault in a native library) takes them all, so keep recorders in their own.
"""
from __future__ import annotations

import gc
import signal
from typing import TYPE_CHECKING, Any

from ..messages.codec import topic_frame
from .bound_ports import OutputPort

if TYPE_CHECKING:
    from .bound_ports import InputPort
    from .node import Node


def co_locate(nodes: list["Node"]) -> list[tuple["Node", str, "Node"]]:
    """Take the endpoints of this process's own publishers out of every input's wiring (before
    setup); returns the in-process links as (subscribing node, input name, publishing node)."""
    by_endpoint = {n.wiring.pub_endpoint: n for n in nodes if n.wiring.pub_endpoint}
    links = []
    for node in nodes:
        for name, spec in node.wiring.inputs.items():
            endpoints = list(spec.get("endpoints", []))
            # a node subscribed to its own topic keeps its socket: it is no peer of itself
            peers = [by_endpoint[e] for e in endpoints if e in by_endpoint and by_endpoint[e] is not node]
            if peers:
                spec["endpoints"] = [e for e in endpoints if e not in by_endpoint or by_endpoint[e] is node]
                links.extend((node, name, p) for p in peers)
    return links


def link_local(publisher: "Node", port: "InputPort") -> None:
    """Feed ``port`` (an input of another node of this process) from ``publisher``'s outputs on its
    topic, without ZeroMQ; the launcher counted it as a subscriber, which the publisher's XPUB will
    never see, so the publisher waits for one fewer before it is ready."""
    key = topic_frame(port.topic)
    for out in publisher._ports.values():
        if isinstance(out, OutputPort) and out.topic_key == key:
            out.local.append(port)
            if out.last_frames is not None:
                port.post_local(out.last_frames)
    publisher._local_subscribers[key] = publisher._local_subscribers.get(key, 0) + 1


def serve(nodes: list["Node"]) -> int:
    """Set up ``nodes`` on one loop, serve until every one has stopped, clean up.

    A node that stops (a finished file source, the launcher's STOP) runs its on_stop and closes
    while the others go on. Returns the process exit code: the highest any node asked for.
    """
    loop = nodes[0]._loop
    for node in nodes[1:]:
        node.join_loop(loop)
    links = co_locate(nodes)
    for node in nodes:
        node.setup()
    for subscriber, input_name, publisher in links:
        link_local(publisher, subscriber.bound_port(input_name))
    for node in nodes:
        node.announce_ready()
    # Start-up objects (modules, params, models) need no more scanning by the collector:
    # fewer and shorter pauses on the per-message path.
    gc.freeze()
    live = list(nodes)
    try:
        while live:
            loop.spin_once(0.1)
            if loop.stopped:
                for node in [n for n in live if n.stopping]:
                    live.remove(node)
                    node.finish()
                loop.stopped = False
    finally:
        errors = []
        for node in live:
            try:
                node.finish()
            except Exception as exc:  # the others still flush their files
                errors.append(exc)
        if errors:
            raise errors[0]
    return max(int(getattr(n, "exit_code", 0) or 0) for n in nodes)


def install_stop_handlers(nodes: list["Node"]) -> None:
    """SIGINT/SIGTERM end every node's loop cleanly (each on_stop runs, files are flushed)."""

    def handler(signum: int, frame: Any) -> None:
        for node in nodes:
            node.request_stop()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
