"""Per-edge statistics: rate from sender stamps, latency, sequence gaps, rejects.

An edge is one (topic, sending node) pair seen by one subscriber; its sequence numbers are read
by the one rule in `messages.sequence`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from ..messages.sequence import DUPLICATE, RESTART, sequence_gap

WINDOW = 512
# The launcher prefixes each line with the receiving node's name.
log = logging.getLogger("mocapgraph.bus")


@dataclass
class EdgeStats:
    """Counters and a ring of recent (publish stamp, latency) for one edge."""

    topic: str
    sender: str
    last_seq: int = 0
    last_publish_ns: int = 0
    received: int = 0
    gaps: int = 0
    duplicates: int = 0
    restarts: int = 0
    # Plain lists: one store per message is cheaper than a numpy element store; numpy is used
    # once a second when the figures are read.
    _pub: list = field(default_factory=lambda: [0] * WINDOW)
    _lat: list = field(default_factory=lambda: [0] * WINDOW)
    _n: int = 0

    def accept(self, seq: int, publish_ns: int, now_ns: int) -> bool:
        """Record one arrival; False when it is a duplicate (a latched resend) to be dropped."""
        lost = sequence_gap(self.last_seq, seq, publish_ns == self.last_publish_ns)
        if lost == DUPLICATE:
            self.duplicates += 1
            return False
        if lost == RESTART:
            self.restarts += 1
            log.info("%s from %s: the sender restarted (sequence %d after %d): a new stream, not loss",
                     self.topic, self.sender, seq, self.last_seq)
        else:
            self.gaps += lost
        self.last_seq = seq
        self.last_publish_ns = publish_ns
        self.received += 1
        i = self._n % WINDOW
        self._pub[i] = publish_ns
        self._lat[i] = now_ns - publish_ns
        self._n += 1
        return True

    def rate_hz(self) -> float:
        """Rate over the window from the sender's own publish stamps (immune to our jitter)."""
        n = min(self._n, WINDOW)
        if n < 2:
            return 0.0
        stamps = self._pub[:n]
        span = float(max(stamps) - min(stamps))
        return (n - 1) * 1e9 / span if span > 0 else 0.0

    def latency_ms(self) -> tuple[float, float]:
        """Median and maximum latency over the window, ms."""
        n = min(self._n, WINDOW)
        if n == 0:
            return float("nan"), float("nan")
        lat = np.asarray(self._lat[:n], np.int64)
        return float(np.median(lat)) / 1e6, float(lat.max()) / 1e6


@dataclass
class InputStats:
    """All edges of one input, plus frames rejected before a sender was known."""

    edges: dict[tuple[str, str], EdgeStats] = field(default_factory=dict)
    rejected: int = 0

    def edge(self, topic: str, sender: str) -> EdgeStats:
        key = (topic, sender)
        e = self.edges.get(key)
        if e is None:
            e = self.edges[key] = EdgeStats(topic, sender)
        return e
