"""Which nodes stopped talking: a node whose diagnostics (1 Hz) stop for STALL_S is stalled.

A stopped process (SIGSTOP, a debugger, a swap storm, an endless loop in a handler) keeps its
pid and its sockets, so only its silence shows it. `Liveness` is pure bookkeeping (the launcher
feeds arrival times and asks for transitions); the socket helpers below feed it.
"""
from __future__ import annotations

from typing import Iterable

import zmq

from ..bus.curve import CurveKeys, make_client
from ..bus.diagnostics import DIAGNOSTICS_TOPIC
from ..messages import DecodeError, decode_envelope
from ..messages.codec import topic_frame

STALL_S = 3.0


class Liveness:
    """Last diagnostics time per node (monotonic s) and the nodes currently reported stalled."""

    def __init__(self, stall_s: float = STALL_S) -> None:
        self.stall_s = stall_s
        self.last: dict[str, float] = {}
        self.stalled: dict[str, float] = {}  # node -> last time it was heard of

    def heard(self, node: str, now: float) -> float | None:
        """Record diagnostics of ``node``; the seconds it was silent when it had been stalled, else None."""
        if node not in self.last and node not in self.stalled:
            return None  # not a node we were told to watch
        since = self.stalled.pop(node, None)
        self.last[node] = now
        return None if since is None else now - since

    def watch(self, node: str, now: float) -> None:
        """Start (or restart, after a respawn) the clock of ``node``."""
        self.stalled.pop(node, None)
        self.last[node] = now

    def forget(self, node: str) -> None:
        self.last.pop(node, None)
        self.stalled.pop(node, None)

    def newly_stalled(self, now: float, running: Iterable[str]) -> list[tuple[str, float]]:
        """Nodes among ``running`` silent for stall_s or more and not yet reported: (name, silent s)."""
        out = []
        for node in running:
            last = self.last.get(node)
            if last is not None and node not in self.stalled and now - last >= self.stall_s:
                self.stalled[node] = last
                out.append((node, now - last))
        return out

    def is_stalled(self, node: str) -> bool:
        return node in self.stalled


def diagnostics_socket(ctx: zmq.Context, endpoints: Iterable[str], curve: CurveKeys | None) -> zmq.Socket:
    """A SUB socket on every node's diagnostics (a CurveZMQ client when the graph has keys)."""
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    if curve is not None:
        make_client(sock, curve)
    sock.setsockopt(zmq.RCVHWM, 1000)
    sock.setsockopt(zmq.SUBSCRIBE, topic_frame(DIAGNOSTICS_TOPIC))
    for ep in endpoints:
        sock.connect(ep)
    return sock


def drain_senders(sock: zmq.Socket) -> list[str]:
    """Sender names of every diagnostics message waiting on ``sock`` (malformed ones skipped)."""
    out = []
    while True:
        try:
            frames = sock.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return out
        try:
            out.append(decode_envelope(frames).sender)
        except DecodeError:
            continue
