"""A running node's bound ports: publishing on the XPUB socket, receiving and decoding on a SUB."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Callable

import zmq

from ..messages import DecodeError, Envelope, Message, decode_envelope, decode_payload, encode
from ..messages.codec import topic_frame
from ..messages.registry import UnknownTypeError, lookup
from .curve import CurveKeys, make_client
from .ports import Input, Output
from .stats import InputStats

if TYPE_CHECKING:
    from .node import Node

# Plain ints: pyzmq's enum flags cost an enum operation per frame on the hot path.
_SNDMORE = int(zmq.SNDMORE)
_NOBLOCK = int(zmq.NOBLOCK)
_POLLIN = int(zmq.POLLIN)
_EVENTS = int(zmq.EVENTS)
UNEXPECTED_LOG_S = 5.0  # at most one line per this many seconds about frames from unexpected senders
BATCH = 256  # messages taken from one input per loop turn, so one busy input cannot starve the others


class OutputPort:
    """A bound output: ``publish(msg)`` sends it to every subscriber of its topic."""

    def __init__(self, node: "Node", decl: Output, topic: str) -> None:
        self.node = node
        self.decl = decl
        self.topic = topic
        self.latched = decl.is_latched
        self.seq = 0
        self.last_frames: list | None = None
        self.topic_key = topic_frame(topic)

    def publish(self, msg: Message, capture_ns: int | None = None) -> None:
        """Send ``msg``. ``capture_ns`` is when the data was captured (defaults to now)."""
        if not isinstance(msg, self.decl.msg_type):
            raise TypeError(f"{self.decl.name} publishes {self.decl.type_name}, not {type(msg).__name__}")
        self.seq += 1
        frames = encode(self.topic, msg, self.seq, time.time_ns() if capture_ns is None else capture_ns,
                        self.node.name, None, self.latched)
        if self.latched:
            frames = [bytes(f) for f in frames]  # keep a copy we own for resends
            self.last_frames = frames
        self._send(frames)

    def publish_frames(self, frames: list, latched: bool = False) -> None:
        """Send already-encoded frames (a bag player's recorded bytes) on this port's topic.

        The header is sent as given (its sequence number and stamps are the caller's); frame 0
        is replaced by this port's topic so that remaps apply.
        """
        frames = list(frames)
        frames[0] = self.topic_key
        if self.latched or latched:
            frames = [bytes(f) for f in frames]
            self.last_frames = frames
        self.seq += 1
        self._send(frames)

    def _send(self, frames: list) -> None:
        send = self.node._pub.send
        copy = len(frames[-1]) < 65536  # zero-copy pays off only for large payloads
        for f in frames[:-1]:
            send(f, _SNDMORE, copy=copy)
        send(frames[-1], 0, copy=copy)


class InputPort:
    """A bound input: its SUB socket, the latest message and envelope, per-edge statistics."""

    def __init__(self, node: "Node", decl: Input, topic: str, senders: list[str] | None = None) -> None:
        self.node = node
        self.decl = decl
        self.topic = topic
        self.latest: Message | None = None
        self.envelope: Envelope | None = None
        self.stats = InputStats(senders)
        self._unexpected_logged = -UNEXPECTED_LOG_S
        self.socket: zmq.Socket | None = None
        self.handler: Callable[..., Any] | None = None

    def open(self, ctx: zmq.Context, endpoints: list[str], curve: "CurveKeys | None" = None) -> zmq.Socket:
        """Create the SUB socket (queue depth from the declaration) connected to ``endpoints``
        (as a CurveZMQ client when the graph has keys)."""
        sock = ctx.socket(zmq.SUB)
        if curve is not None:
            make_client(sock, curve)
        sock.setsockopt(zmq.RCVHWM, 0 if self.decl.queue <= 0 else self.decl.queue)
        sock.setsockopt(zmq.RECONNECT_IVL, 20)
        sock.setsockopt(zmq.RECONNECT_IVL_MAX, 500)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.SUBSCRIBE, topic_frame(self.topic))
        for ep in endpoints:
            sock.connect(ep)
        self.socket = sock
        return sock

    def on_readable(self) -> None:
        """Take up to BATCH messages: count each on its edge, decode, hand to the handler."""
        sock = self.socket
        loop = self.node._loop
        newest: tuple[Envelope, list[bytes]] | None = None
        for i in range(BATCH):
            # Poll said readable for the first; ask before the others: a raised zmq.Again costs
            # more than the message itself.
            if i and not sock.getsockopt(_EVENTS) & _POLLIN:
                break
            try:
                frames = sock.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            now = time.time_ns()
            try:
                env = decode_envelope(frames)
            except DecodeError as exc:
                self.stats.rejected += 1
                self._reject(exc)
                continue
            if env.topic != self.topic:
                continue
            edge = self.stats.edge(env.topic, env.sender)
            if edge is None:
                self._unexpected(env.sender)
                continue
            if not edge.accept(env.seq, env.publish_ns, now):
                continue
            if self.decl.raw:
                self.envelope = env
                if self.handler is not None:
                    self.handler(env, frames)
                continue
            if self.decl.latest_only:
                newest = (env, frames)
                continue
            self._deliver(env, frames)
            if loop.stopped:
                return
        if newest is not None:
            self._deliver(*newest)

    def _deliver(self, env: Envelope, frames: list[bytes]) -> None:
        want = self.decl.msg_type
        try:
            cls = lookup(env.type_name) if want is None else want
            if want is not None and env.type_name != want.type_name:
                raise DecodeError(f"type {env.type_name} where {want.type_name} was expected")
            msg = decode_payload(cls, env, frames)
        except (DecodeError, UnknownTypeError) as exc:
            self.stats.rejected += 1
            self._reject(exc)
            return
        self.latest = msg
        self.envelope = env
        if self.handler is not None:
            self.handler(msg)

    def _unexpected(self, sender: str) -> None:
        n = self.stats.unexpected
        now = time.monotonic()
        if n <= 3 or now - self._unexpected_logged >= UNEXPECTED_LOG_S:  # logged, but never a flood
            self._unexpected_logged = now
            self.node.log.warning("input %s: %d frame(s) from senders the wiring does not name (latest %r) "
                                  "rejected", self.decl.name, n, sender[:64])

    def _reject(self, exc: Exception) -> None:
        n = self.stats.rejected
        if n <= 5 or n % 1000 == 0:  # logged, but never a flood
            self.node.log.warning("input %s: rejected frame #%d: %s", self.decl.name, n, exc)
