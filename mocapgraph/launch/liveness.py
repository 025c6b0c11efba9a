"""Which nodes stopped talking: a node whose diagnostics (1 Hz) stop for STALL_S is stalled, and
an output that stopped while its node's inputs kept receiving is a stalled output.

A stopped process (SIGSTOP, a debugger, a swap storm, an endless loop in a handler) keeps its
pid and its sockets, so only its silence shows it. A node that still talks but no longer
publishes what it is fed (a stream it drops, a model it refuses, a handler that fails every
frame) shows in its diagnostics: its inputs' received counts go on, an output's sent count stops.
`Liveness` and `OutputWatch` are pure bookkeeping (the launcher feeds arrival times and counts and
asks for transitions); the socket helpers below feed them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Container, Iterable

import zmq

from ..bus.curve import CurveKeys, make_client
from ..bus.diagnostics import DIAGNOSTICS_TOPIC
from ..messages import DecodeError, Diagnostics, decode
from ..messages.codec import topic_frame

if TYPE_CHECKING:
    from .check import CheckedGraph

STALL_S = 3.0
#: an output is watched once it advanced in this many diagnostics in a row (a steady stream) ...
STEADY_REPORTS = 3
#: ... at this rate at least, Hz (status messages at 1 Hz and on change are not streams)
STEADY_HZ = 2.0
#: and it is stalled when silent for max(STALL_S, this many of its own periods) while inputs received
STALL_PERIODS = 10


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


class _Out:
    """One output's sent count as the diagnostics showed it, and when it last moved (monotonic s)."""

    __slots__ = ("sent", "moved_at", "steady", "slow", "rate_hz", "inputs_at", "stalled")

    def __init__(self, sent: int, now: float, inputs: int) -> None:
        self.sent, self.moved_at, self.steady, self.slow, self.rate_hz = sent, now, 0, 0, 0.0
        self.inputs_at = inputs      # the node's inputs' received count when it last moved
        self.stalled = False

    def moved(self, sent: int, now: float) -> None:
        """The count advanced to ``sent``: count a steady interval, or a slow one. A steady stream
        keeps its rate through one slow interval, for the interval in which a stream stops is
        partial (a frame or two since the last report) and must not unwatch it; two slow ones in a
        row (a stream that really slowed down) start the count again."""
        dt = now - self.moved_at
        rate = (sent - self.sent) / dt if dt > 0 else self.rate_hz
        if rate >= STEADY_HZ:
            self.steady, self.slow, self.rate_hz = self.steady + 1, 0, rate
        else:
            self.slow += 1
            if self.steady < STEADY_REPORTS or self.slow >= 2:
                self.steady, self.rate_hz = 0, rate


class OutputWatch:
    """Outputs that flowed steadily and stopped while their node's inputs kept receiving.

    ``watched``: per node, the output topics to watch (not latched ones, not diagnostics: those
    are published on change).
    """

    def __init__(self, watched: dict[str, set[str]], stall_s: float = STALL_S) -> None:
        self.watched = watched
        self.stall_s = stall_s
        self.outs: dict[tuple[str, str], _Out] = {}
        self.inputs: dict[str, tuple[int, float]] = {}   # node -> (received by its inputs, when heard)

    @classmethod
    def of_graph(cls, graph: "CheckedGraph") -> "OutputWatch":
        """Every node's outputs but latched ones and diagnostics."""
        return cls({rn.name: {t for port, t in rn.outputs.items()
                              if not rn.iface.outputs[port].is_latched and t != DIAGNOSTICS_TOPIC}
                    for rn in graph.nodes})

    def forget(self, node: str) -> None:
        """A node restarted: its counts start again."""
        self.inputs.pop(node, None)
        for key in [k for k in self.outs if k[0] == node]:
            del self.outs[key]

    def heard(self, node: str, d: Diagnostics, now: float) -> tuple[list[tuple[str, float, int]],
                                                                     list[tuple[str, float]]]:
        """Take the diagnostics ``d`` of ``node``: (newly stalled outputs as (topic, silent s, messages
        its inputs received meanwhile), outputs flowing again as (topic, silent s))."""
        watched = self.watched.get(node)
        if not watched:
            return [], []
        received = int(sum(int(x) for x in d.edge_received))
        before, _ = self.inputs.get(node, (received, now))
        if received < before:   # a restarted node (a process group member): counts from 0 again
            self.forget(node)
            before = received
        self.inputs[node] = (received, now)
        live = received > before   # its inputs received since its last diagnostics
        stalled, resumed = [], []
        for topic, sent in zip(d.output_topics, d.output_sent):
            if topic not in watched:
                continue
            sent = int(sent)
            o = self.outs.get((node, topic))
            if o is None or sent < o.sent:
                self.outs[(node, topic)] = _Out(sent, now, received)
                continue
            if sent > o.sent:
                if o.stalled:
                    resumed.append((topic, now - o.moved_at))
                o.moved(sent, now)
                o.sent, o.moved_at, o.inputs_at, o.stalled = sent, now, received, False
                continue
            silent = now - o.moved_at
            fed = received - o.inputs_at
            if (not o.stalled and live and o.steady >= STEADY_REPORTS and fed >= 3
                    and silent >= max(self.stall_s, STALL_PERIODS / o.rate_hz)):
                o.stalled = True
                stalled.append((topic, silent, fed))
        return stalled, resumed

    def stalled_outputs(self, node: str) -> list[str]:
        return sorted(t for (n, t), o in self.outs.items() if n == node and o.stalled)


def heard_lines(liveness: Liveness, outputs: OutputWatch, arrivals: Iterable[tuple[str, Diagnostics]],
                now: float, nodes: Container[str]) -> list[str]:
    """Feed diagnostics of the launcher's ``nodes`` to both; the launcher's lines about what changed."""
    lines = []
    for sender, d in arrivals:
        if sender not in nodes:
            continue
        silent = liveness.heard(sender, now)
        if silent is not None:
            lines.append(f"[launch] node {sender} is responding again after {silent:.1f} s of silence")
        stalled, resumed = outputs.heard(sender, d, now)
        for topic, silent, fed in stalled:
            lines.append(f"[launch] node {sender} output {topic} stalled: nothing published for {silent:.1f} s "
                         f"while its inputs received {fed} messages (see its log: a refused model or layout?)")
        for topic, silent in resumed:
            lines.append(f"[launch] node {sender} output {topic} is flowing again after {silent:.1f} s")
    return lines


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


def drain_diagnostics(sock: zmq.Socket) -> list[tuple[str, Diagnostics]]:
    """(sender, message) of every diagnostics message waiting on ``sock`` (malformed ones skipped)."""
    out = []
    while True:
        try:
            frames = sock.recv_multipart(zmq.NOBLOCK)
        except zmq.Again:
            return out
        try:
            env, msg = decode(frames)
        except DecodeError:
            continue
        if isinstance(msg, Diagnostics):
            out.append((env.sender, msg))
