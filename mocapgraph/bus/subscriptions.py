"""A publisher's view of its subscribers: which it applies, counts for the start-up handshake, latched resends.

The XPUB socket runs in manual mode (ZMQ_XPUB_MANUAL): it reports every subscription and applies
none by itself. Only subscriptions to this node's own topics (and the empty prefix: everything
it publishes) are applied, to the peer that sent them; anything else is counted and forgotten.
So a peer holds at most one entry per own topic in the socket's subscription trie, however many
it sends (ZeroMQ keeps a peer's repeats of one prefix as one entry), and junk topics cost no
memory (left to ZeroMQ, 200 000 distinct ones of 212 bytes took a publisher from 32 to 1950 MB).
Only subscriptions to own topics are counted, and a latched value is re-sent at most once per
LATCHED_RESEND_S per topic: the XPUB sends it to every subscriber of the topic, so a flood of
subscriptions must not multiply it. At most DRAIN_BATCH events are taken per loop turn, so a
flood leaves the node's timers and handlers their turns.
"""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Callable, Iterable

import zmq

if TYPE_CHECKING:
    from .bound_ports import OutputPort

LATCHED_RESEND_S = 0.05  # a latched value goes out at most this often per topic, however many subscribe
DRAIN_BATCH = 2000  # subscription events taken per loop turn (the rest on the next turns)
CHECK_EVERY = 64    # subscription events taken between two looks for floods
_SUBSCRIBE = int(zmq.SUBSCRIBE)
_UNSUBSCRIBE = int(zmq.UNSUBSCRIBE)


class Subscriptions:
    """Subscription counts per own topic key and the latched-resend pacing of one XPUB socket.

    ports: callable giving the node's bound output ports now; later: schedules a one-shot
    callback (the node's call_later); timers_on: whether such callbacks run yet; flood_check:
    called before a batch goes on past a foreign subscription or many events (`peer_guard`).
    """

    def __init__(self, ports: Callable[[], Iterable["OutputPort"]], later: Callable[[float, Callable[[], None]], object],
                 timers_on: Callable[[], bool], flood_check: Callable[[], None] = lambda: None) -> None:
        self._ports = ports
        self._flood_check = flood_check
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

    def drain(self, pub: zmq.Socket) -> bool:
        """Read waiting subscription events (DRAIN_BATCH at most): apply those to our topics to the
        peer that sent each, re-send latched values of the topics asked for. True when events remain."""
        ours = self.by_topic()
        wanted: set[bytes] = set()
        foreign = 0
        for i in range(DRAIN_BATCH):
            try:
                ev = pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            key = ev[1:]
            if not ev or ev[0] > 1 or (key and key not in ours):
                self.foreign += 1
                foreign += 1
                if foreign % CHECK_EVERY == 1:   # a flood's first sign: cut its peer before ZeroMQ takes more
                    self._flood_check()
                continue
            if i and i % CHECK_EVERY == 0:
                self._flood_check()
            # (applies to the peer of the event just received: ZeroMQ's manual mode)
            pub.setsockopt(_SUBSCRIBE if ev[0] else _UNSUBSCRIBE, key)
            if not ev[0] or not key:   # an unsubscription, or all topics (no handshake count)
                continue
            self.counts[key] = self.counts.get(key, 0) + 1
            wanted.add(key)
        for key in wanted:
            if any(p.last_frames is not None for p in ours[key]):
                self.resend(key)
        return bool(pub.getsockopt(zmq.EVENTS) & zmq.POLLIN)

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
