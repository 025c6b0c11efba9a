"""Clocks between machines: each launcher answers and sends time requests, so every machine of a
split graph knows the others' clock offsets and cross-machine latency figures are true.

A launcher run with ``--machine NAME`` of a graph with other machines listens for time requests on
UDP at its machine's address and the port of its machine's first node (``host:`` and ``port:`` of
the graph; UDP and TCP ports are separate, so the node's publisher keeps its TCP port). It asks
every other machine the same way, ten times a second for the first few seconds and then once a
second, and keeps each peer's offset in a :class:`~mocapgraph.messages.clock_sync.PeerClock`
(NTP's arithmetic, the exchange of least round trip). The offsets go to the launcher's own nodes
(a ``clocks`` control message: sender node -> its machine's offset), which add them to their
incoming edges' latency (a message's publish stamp is its sender's clock) and report the machine
clocks in their Diagnostics; the manifest lists them under ``clocks``.

A request and its answer are the same size (no amplification). With a CurveZMQ ``security:`` both
carry an HMAC-SHA256 keyed with the graph's secret key, so only the graph's machines are answered
and believed; without one they are plaintext, as the bus is. Packets that are not ours, too short,
or fail the HMAC are counted and dropped.
"""
from __future__ import annotations

import hashlib
import hmac
import os
import socket
import struct
import time
from dataclasses import dataclass

from ..messages.clock_sync import PeerClock, PeerStats, wall_ns
from .check import CheckedGraph

MAGIC = b"MGC1"
ASK, ANSWER = b"Q", b"A"
BODY = struct.Struct("<4sc3xIqqq")     # magic, kind, pad, id, t1, t2, t3
MAC_BYTES = 32
FAST_S, FAST_FOR_S, SLOW_S = 0.1, 3.0, 1.0
MAX_PER_TURN = 256


@dataclass(frozen=True)
class Peer:
    machine: str
    address: tuple[str, int]


def machine_addresses(graph: CheckedGraph) -> dict[str, tuple[str, int]]:
    """Each named machine's (host, port): those of its first node in the graph."""
    out: dict[str, tuple[str, int]] = {}
    for rn in graph.nodes:
        if rn.spec.machine and rn.spec.machine not in out:
            out[rn.spec.machine] = (rn.spec.host, rn.spec.port)
    return out


class MachineClocks:
    """This launcher's time service and its view of the other machines' clocks (see module doc)."""

    def __init__(self, graph: CheckedGraph, machine: str, key: bytes | None = None) -> None:
        addrs = machine_addresses(graph)
        self.machine = machine
        self.key = key
        self.peers = [Peer(m, a) for m, a in addrs.items() if m != machine]
        self.clocks = {p.machine: PeerClock() for p in self.peers}
        self.node_machine = {rn.name: rn.spec.machine for rn in graph.nodes if rn.spec.machine}
        self.dropped = 0
        self._pending: dict[int, tuple[str, int]] = {}     # request id -> (machine, t1)
        self._next_id = int.from_bytes(os.urandom(4), "little")
        self._started = time.monotonic()
        self._due = 0.0
        self._warned: set[str] = set()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setblocking(False)
        self.sock.bind(addrs[machine])

    def fileno(self) -> int:
        return self.sock.fileno()

    def close(self) -> None:
        self.sock.close()

    # ----- packets -------------------------------------------------------------------------------
    def _pack(self, kind: bytes, rid: int, t1: int, t2: int = 0, t3: int = 0) -> bytes:
        body = BODY.pack(MAGIC, kind, rid, t1, t2, t3)
        return body + (hmac.new(self.key, body, hashlib.sha256).digest() if self.key else b"")

    def _unpack(self, data: bytes) -> tuple | None:
        want = BODY.size + (MAC_BYTES if self.key else 0)
        if len(data) != want or not data.startswith(MAGIC):
            return None
        body = data[:BODY.size]
        if self.key and not hmac.compare_digest(data[BODY.size:], hmac.new(self.key, body, hashlib.sha256).digest()):
            return None
        return BODY.unpack(body)[1:]

    # ----- the loop's work -------------------------------------------------------------------------
    def serve(self) -> bool:
        """Answer waiting requests, take waiting answers; True when an estimate changed."""
        changed = False
        for _ in range(MAX_PER_TURN):
            try:
                data, addr = self.sock.recvfrom(256)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:                      # an ICMP error for a peer not up yet
                continue
            t_in = wall_ns()
            got = self._unpack(data)
            if got is None:
                self.dropped += 1
                continue
            kind, rid, t1, _, _ = got
            if kind == ASK:
                try:
                    self.sock.sendto(self._pack(ANSWER, rid, t1, t_in, wall_ns()), addr)
                except OSError:
                    pass
            elif kind == ANSWER and rid in self._pending:
                machine, sent = self._pending.pop(rid)
                _, _, _, t2, t3 = got
                if sent == t1:
                    self.clocks[machine].update(t1, t2, t3, t_in)
                    changed = True
            else:
                self.dropped += 1
        return changed

    def probe(self) -> None:
        """Ask every peer once when it is time (fast at first, then once a second)."""
        now = time.monotonic()
        if now < self._due:
            return
        self._due = now + (FAST_S if now - self._started < FAST_FOR_S else SLOW_S)
        if len(self._pending) > 64 * max(1, len(self.peers)):
            self._pending.clear()                # answers that never came
        for p in self.peers:
            self._next_id = (self._next_id + 1) & 0xFFFFFFFF
            t1 = wall_ns()
            self._pending[self._next_id] = (p.machine, t1)
            try:
                self.sock.sendto(self._pack(ASK, self._next_id, t1), p.address)
            except OSError:
                pass

    def silent_peers(self, after_s: float) -> list[Peer]:
        """Peers never heard from ``after_s`` after start, each returned once (for one log line)."""
        if time.monotonic() - self._started < after_s:
            return []
        out = [p for p in self.peers if not self.clocks[p.machine].samples and p.machine not in self._warned]
        self._warned.update(p.machine for p in out)
        return out

    # ----- results -------------------------------------------------------------------------------
    def stats(self) -> dict[str, PeerStats]:
        return {m: c.stats() for m, c in self.clocks.items()}

    def sender_offsets(self) -> dict[str, int]:
        """Node name -> its machine's clock minus ours, ns, for every node of a measured machine."""
        offs = {m: st.offset_ns for m, st in self.stats().items() if st.samples}
        return {n: int(round(offs[m])) for n, m in self.node_machine.items() if m in offs}
