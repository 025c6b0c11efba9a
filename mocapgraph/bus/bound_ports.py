"""A running node's bound ports: publishing on the XPUB socket, receiving and decoding on a SUB.

Between nodes of one process (a launch graph's ``process:`` group) an output also hands its frames
straight to the subscribing input ports (`OutputPort.local`), which take them through the same
checks, statistics and decoding as frames from a socket: at once (the subscriber's handler runs
inside ``publish``, which is what makes the hop cost microseconds), or on the loop's next turn
when the publisher is itself being fed in process (so that no handler is ever re-entered).
"""
from __future__ import annotations

import time
from collections import deque
from typing import TYPE_CHECKING, Any, Callable

import zmq

from ..messages import DecodeError, Envelope, Message, decode_envelope, decode_payload
from ..messages.codec import array_frames, encode_head, local_copy, local_envelope, topic_frame
from ..messages.clock_sync import wall_ns
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
#: in-process messages held for an input with no queue limit (a recorder's): more than any burst
#: one loop turn publishes; beyond it the oldest go, counted as gaps like a full socket queue's
LOCAL_QUEUE_MAX = 10_000
#: bytes: a frame smaller than this is copied when sent, so once ``publish`` returns its message's
#: arrays may be written again (a node reusing its buffers relies on it); larger frames go
#: zero-copy (the copy would cost more than the send) and must be left alone after publishing
COPY_BELOW = 65536


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
        #: input ports of nodes in this process subscribed to this topic (fed without ZeroMQ)
        self.local: list[InputPort] = []

    def publish(self, msg: Message, capture_ns: int | None = None) -> None:
        """Send ``msg``. ``capture_ns`` is when the data was captured (defaults to now)."""
        if not isinstance(msg, self.decl.msg_type):
            raise TypeError(f"{self.decl.name} publishes {self.decl.type_name}, not {type(msg).__name__}")
        self.seq += 1
        head, arrays = encode_head(self.topic, msg, self.seq, wall_ns() if capture_ns is None else capture_ns,
                                   self.node.name, None, self.latched)
        if self.latched or not self.local:
            frames = head + array_frames(arrays)
            if self.latched:
                frames = [bytes(f) for f in frames]  # keep a copy we own for resends
                self.last_frames = frames
            self._send(frames, msg)
            return
        # this process's subscribers first, before the socket frames are even assembled (the hop
        # of a pipeline composed in one process); then ZeroMQ
        self.send_zmq(self._send_local(head, msg, arrays))

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

    def _send(self, frames: list, msg: Message | None = None) -> None:
        """To the subscribers in this process (``msg``: what ``frames`` encode, handed over without
        decoding), then over ZeroMQ. In that order: a pipeline composed in one process runs its
        next stage before the copies for recorders and viewers go out (the hop's latency)."""
        if self.local:
            self._send_local(frames, msg)
        self.send_zmq(frames)

    def send_zmq(self, frames: list) -> None:
        """To the subscribers over ZeroMQ only (a latched value re-sent to a late joiner)."""
        send = self.node._pub.send
        copy = len(frames[-1]) < COPY_BELOW  # zero-copy pays off only for large payloads
        for f in frames[:-1]:
            send(f, _SNDMORE, copy=copy)
        send(frames[-1], 0, copy=copy)

    def _send_local(self, frames: list, msg: Message | None, arrays: tuple | None = None) -> list:
        """Hand the message to this process's subscribers: at once when no in-process delivery is
        under way (the handler publishing is then the only one running, and it is never one of
        them: no handler is re-entered), else queued for the loop's next turn.

        Each gets its own copy (`local_copy`: read-only arrays, shapes checked) beside the header
        frames; raw subscribers (recorders) and messages that fail the check get the bytes.
        ``arrays``: ``frames`` are the head only (`encode_head`), these the payload; returns the
        whole frames (for the socket)."""
        whole = frames if arrays is None else None
        head = frames if arrays is not None else frames[:3]
        owned: list | None = None
        env = None if msg is None else local_envelope(self.topic, msg._info.name, self.node.name, frames[1])
        items = []
        for port in self.local:
            copy = None
            if msg is not None and not port.decl.raw:
                try:
                    copy = local_copy(msg)
                except DecodeError:
                    copy = None   # the subscriber decodes the bytes and rejects them, as over a socket
            if copy is None and owned is None:
                if whole is None:
                    whole = frames + array_frames(arrays)
                # bytes of our own: array frames are views of the message, which its sender may reuse
                owned = [f if type(f) is bytes else bytes(f) for f in whole]
            items.append((port, owned if copy is None else head, copy))
        loop = self.node._loop
        if loop.delivering:
            for port, fr, copy in items:
                port.post_local(fr, copy, env)
        else:
            loop.delivering = True
            try:
                for port, fr, copy in items:
                    port.take_now(fr, copy, env)
            finally:
                loop.delivering = False
        return whole if whole is not None else frames + array_frames(arrays)


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
        self._local: deque = deque(maxlen=decl.queue if decl.queue > 0 else LOCAL_QUEUE_MAX)
        self.closed = False

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
        node = self.node
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
            newest = self._take(frames, newest)
            if node.stopping:   # (this node: another of its process stopping does not cut the batch)
                return
        if newest is not None:
            self._deliver(*newest)

    def post_local(self, frames: list, msg: Message | None = None, env: Envelope | None = None) -> None:
        """Queue a message published by a node of this process (taken on the loop's next turn):
        its frames (the header at least) and, unless they are to be decoded, the message itself and
        its envelope."""
        if self.closed or self.node.stopping:   # leaving: as its socket's queue would, it takes no more
            return
        self._local.append((frames, msg, env))
        self.node._loop.local_ready[self] = None

    def take_now(self, frames: list, msg: Message | None = None, env: Envelope | None = None) -> None:
        """Take a message published by a node of this process now (after any queued before it)."""
        if self.closed or self.node.stopping:
            return
        if self._local:   # earlier ones wait: in order
            self._local.append((frames, msg, env))
            self.on_local()
            return
        newest = self._take(frames, None, msg, env)   # (on_local of this one message, without the queue)
        if newest is not None and not self.node.stopping:
            self._deliver(*newest)

    def has_local(self) -> bool:
        return bool(self._local)

    def on_local(self) -> None:
        """Take the queued in-process messages, as `on_readable` takes a socket's."""
        queue = self._local
        node = self.node
        newest: tuple[Envelope, list[bytes]] | None = None
        while queue:
            frames, msg, env = queue.popleft()
            newest = self._take(frames, newest, msg, env)
            if node.stopping:
                return
        if newest is not None:
            self._deliver(*newest)

    def _take(self, frames: list, newest: tuple | None, msg: Message | None = None,
              env: Envelope | None = None) -> tuple | None:
        """Check, count and hand on one message (``msg``, ``env``: already decoded, from this
        process); returns the newest held back (``latest_only``)."""
        now = wall_ns()
        if env is None:
            try:
                env = decode_envelope(frames)
            except DecodeError as exc:
                self.stats.rejected += 1
                self._reject(exc)
                return newest
        if env.topic != self.topic:
            return newest
        edge = self.stats.edge(env.topic, env.sender)
        if edge is None:
            self._unexpected(env.sender)
            return newest
        if not edge.accept(env.seq, env.publish_ns, now, env.stream):
            return newest
        if self.decl.raw:
            self.envelope = env
            if self.handler is not None:
                self.handler(env, frames)
            return newest
        if self.decl.latest_only:
            return (env, frames, msg)
        self._deliver(env, frames, msg)
        return newest

    def _deliver(self, env: Envelope, frames: list[bytes], msg: Message | None = None) -> None:
        want = self.decl.msg_type
        try:
            cls = lookup(env.type_name) if want is None else want
            if want is not None and env.type_name != want.type_name:
                raise DecodeError(f"type {env.type_name} where {want.type_name} was expected")
            if msg is None:
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
