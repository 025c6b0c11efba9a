"""Per-edge statistics: rate from sender stamps, latency, sequence gaps, anomalies, rejects.

An edge is one (topic, sending node) pair seen by one subscriber; its sequence numbers are read
by the one rule in `messages.sequence`. The table of edges is bounded: only the senders the
wiring names get an edge (plus at most MAX_FREE_EDGES others where the wiring allows unnamed
senders: external publishers, bag replays); frames of any other sender are rejected and counted
together as "unexpected", so junk with a fresh sender name per frame costs no memory.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from typing import Iterable

import numpy as np

from ..messages.sequence import DUPLICATE, RESTART, StreamTracker

WINDOW = 512
#: in the wiring's sender list: senders not named are allowed too (up to MAX_FREE_EDGES of them)
ANY_SENDER = "*"
MAX_FREE_EDGES = 8
RESTART_LOG_S = 5.0  # at most one line per edge per this many seconds about restarts (after the first 3)
# The launcher prefixes each line with the receiving node's name.
log = logging.getLogger("mocapgraph.bus")


@dataclass
class EdgeStats:
    """Counters and a ring of recent (publish stamp, latency) for one edge."""

    topic: str
    sender: str
    received: int = 0
    #: the sequence rule's state and counts (gaps, duplicates, restarts, anomalies)
    seq: StreamTracker = field(default_factory=StreamTracker)
    # Plain lists: one store per message is cheaper than a numpy element store; numpy is used
    # once a second when the figures are read.
    _pub: list = field(default_factory=lambda: [0] * WINDOW)
    _lat: list = field(default_factory=lambda: [0] * WINDOW)
    _n: int = 0
    _restart_logged: float = -RESTART_LOG_S

    @property
    def gaps(self) -> int:
        return self.seq.gaps

    @property
    def duplicates(self) -> int:
        """Frames dropped: resends and suspected duplicates (at most one in a row)."""
        return self.seq.duplicates

    @property
    def restarts(self) -> int:
        return self.seq.restarts

    @property
    def anomalies(self) -> int:
        """Jumps beyond the believable (forged numbers, missed restarts): resynchronised, not loss."""
        return self.seq.anomalies

    @property
    def last_seq(self) -> int:
        return self.seq.last

    def accept(self, seq: int, publish_ns: int, now_ns: int, stream: int = 0) -> bool:
        """Record one arrival (``stream``: the sender's stream id); False when it is a duplicate
        to be dropped."""
        t = self.seq
        if seq == t.last + 1 and stream == t.stream:   # the usual case: the next number of the stream
            t.last, t.last_stamp, t.suspect, t.jump = seq, publish_ns, False, 0
        else:
            before = t.last
            code = t.take(stream, seq, publish_ns)
            if code == DUPLICATE:
                return False
            if code == RESTART:
                self._log_restart(seq, before)
        self.received += 1
        i = self._n % WINDOW
        self._pub[i] = publish_ns
        self._lat[i] = now_ns - publish_ns
        self._n += 1
        return True

    def _log_restart(self, seq: int, before: int) -> None:
        now = time.monotonic()
        n = self.seq.restarts
        if n <= 3 or now - self._restart_logged >= RESTART_LOG_S:   # a flood of forged streams is no log flood
            self._restart_logged = now
            log.info("%s from %s: the sender restarted (sequence %d after %d): a new stream, not loss "
                     "(%d restart(s))", self.topic, self.sender, seq, before, n)

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


class InputStats:
    """All edges of one input, frames rejected before a sender was known, unexpected senders.

    ``senders``: the sending nodes the wiring names (None: a node run by hand, any sender up to
    MAX_FREE_EDGES); ANY_SENDER among them allows unnamed senders up to that bound too.
    """

    def __init__(self, senders: Iterable[str] | None = None) -> None:
        names = None if senders is None else set(senders)
        self.edges: dict[str, EdgeStats] = {}
        self.expected: frozenset[str] = frozenset(names - {ANY_SENDER}) if names is not None else frozenset()
        self.free_left = MAX_FREE_EDGES if names is None or ANY_SENDER in names else 0
        self.rejected = 0
        #: frames from senders that got no edge (not named, and the free edges used up)
        self.unexpected = 0

    def edge(self, topic: str, sender: str) -> EdgeStats | None:
        """The edge of ``sender``; None (counted as unexpected) for a sender that gets none."""
        e = self.edges.get(sender)
        if e is None:
            if sender in self.expected:
                pass
            elif self.free_left > 0:
                self.free_left -= 1
            else:
                self.unexpected += 1
                return None
            e = self.edges[sender] = EdgeStats(topic, sender)
        return e
