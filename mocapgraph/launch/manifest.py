"""Client side of the launcher's manifest: which topics exist, their types and publishers."""
from __future__ import annotations

import json
from typing import Any

import zmq

from ..messages.codec import topic_frame
from .supervisor import default_master


class NoGraphError(RuntimeError):
    """No launcher answers at the master endpoint."""


def fetch_manifest(master: str | None = None, timeout_s: float = 2.0) -> dict[str, Any]:
    """The running graph's manifest; NoGraphError when nothing answers in ``timeout_s``."""
    master = master or default_master()
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.REQ)
    s.setsockopt(zmq.LINGER, 0)
    try:
        s.connect(master)
        s.send(b"manifest")
        if not s.poll(int(timeout_s * 1000)):
            raise NoGraphError(f"no running graph answers at {master} (start one with 'mocapgraph launch FILE', "
                               "or set MOCAPGRAPH_MASTER)")
        return json.loads(s.recv())
    finally:
        s.close(0)


def topic_entry(manifest: dict[str, Any], topic: str) -> dict[str, Any]:
    """The manifest entry of ``topic``; KeyError with the known topics when absent."""
    try:
        return manifest["topics"][topic]
    except KeyError:
        known = ", ".join(sorted(manifest["topics"]))
        raise KeyError(f"no topic {topic!r} in the running graph (topics: {known})") from None


def subscribe(manifest: dict[str, Any], topics: list[str], hwm: int = 0) -> zmq.Socket:
    """A SUB socket connected to every publisher of ``topics`` (hwm 0: never drop)."""
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.RCVHWM, hwm)
    s.setsockopt(zmq.LINGER, 0)
    endpoints: set[str] = set()
    for t in topics:
        entry = topic_entry(manifest, t)
        endpoints.update(p["endpoint"] for p in entry["publishers"])
        s.setsockopt(zmq.SUBSCRIBE, topic_frame(t))
    for ep in sorted(endpoints):
        s.connect(ep)
    return s
