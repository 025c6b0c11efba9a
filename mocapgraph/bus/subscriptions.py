"""A publisher's view of its subscribers: counts for the start-up handshake, latched resends.

The XPUB socket reports every subscription. Only subscriptions to this node's own topics are
counted (junk topics cost nothing), and a latched value is re-sent at most once per
LATCHED_RESEND_S per topic: the XPUB sends it to every subscriber of the topic, so a flood of
subscriptions must not multiply it.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable, Iterable

import zmq

if TYPE_CHECKING:
    from .bound_ports import OutputPort

LATCHED_RESEND_S = 0.05  # a latched value goes out at most this often per topic, however many subscribe


class Subscriptions:
    """Subscription counts per own topic key and the latched-resend pacing of one XPUB socket.

    ports: callable giving the node's bound output ports now; later: schedules a one-shot
    callback (the node's call_later); timers_on: whether such callbacks run yet.
    """

    def __init__(self, ports: Callable[[], Iterable["OutputPort"]], later: Callable[[float, Callable[[], None]], object],
                 timers_on: Callable[[], bool]) -> None:
        self._ports = ports
        self._later = later
        self._timers_on = timers_on
        self.counts: dict[bytes, int] = {}  # own topic keys only: bounded
        self.foreign = 0  # subscriptions to topics we do not publish (counted, ignored)
        self.resends = 0  # latched values re-sent to late subscribers since start
        self._resent_at: dict[bytes, float] = {}
        self._pending: set[bytes] = set()

    def by_topic(self) -> dict[bytes, list["OutputPort"]]:
        ours: dict[bytes, list[OutputPort]] = {}
        for port in self._ports():
            ours.setdefault(port.topic_key, []).append(port)
        return ours

    def drain(self, pub: zmq.Socket) -> None:
        """Read every waiting subscription event; re-send latched values of the topics asked for."""
        ours = self.by_topic()
        wanted: set[bytes] = set()
        while True:
            try:
                ev = pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            if not ev or ev[0] != 1:
                continue
            key = ev[1:]
            if key not in ours:
                self.foreign += 1
                continue
            self.counts[key] = self.counts.get(key, 0) + 1
            wanted.add(key)
        for key in wanted:
            if any(p.last_frames is not None for p in ours[key]):
                self.resend(key)

    def resend(self, key: bytes) -> None:
        """Send the latched value(s) of topic ``key`` now, or once after the pause when one just went."""
        now = time.monotonic()
        last = self._resent_at.get(key, -LATCHED_RESEND_S)
        if now - last >= LATCHED_RESEND_S or not self._timers_on():
            self._resent_at[key] = now
            self._pending.discard(key)
            for port in self.by_topic().get(key, []):
                if port.last_frames is not None:
                    port.send_zmq(port.last_frames)   # a late joiner over ZeroMQ: not again to this process
                    self.resends += 1
        elif key not in self._pending:
            self._pending.add(key)
            self._later(last + LATCHED_RESEND_S - now, lambda: self.resend(key))
