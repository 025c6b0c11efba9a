"""Per-peer bound on what subscribers may send a publisher: a peer that floods it is cut off.

ZeroMQ's XPUB stores every subscription a peer sends in a trie (about 40 bytes per byte of a new
prefix: 200 000 distinct subscriptions of 212 bytes took a publisher from 32 to 1950 MB), in
manual mode too (it keeps them to unsubscribe when the peer leaves), and offers no limit. A
subscriber sends a publisher nothing but its handshake and a few subscriptions (under a
kilobyte). When subscriptions the node does not serve arrive, the guard looks at every accepted
connection and shuts down one that has sent more than PEER_BYTES in all (TCP: the kernel's
TCP_INFO, Linux) or has more than BACKLOG_BYTES waiting unread (any socket, ipc too: ZeroMQ stops
reading a peer whose queue is full, so a flooder's bytes pile up in the kernel); ZeroMQ then drops
the peer and the subscriptions it held, and the freed heap is given back (glibc's malloc_trim).
The socket's receive queue is kept short (`RCVHWM` below), so that ZeroMQ takes no more of a
flooding peer's subscriptions than one queue's worth before the guard looks, and a message longer
than any subscription the node serves makes ZeroMQ drop its peer at once (`limit_inbound`).
"""
from __future__ import annotations

import ctypes
import fcntl
import itertools
import logging
import os
import socket
import struct
import termios
import time
from typing import Callable

import zmq

#: bytes a peer may send a publisher in one connection (handshakes, CurveZMQ, hundreds of subscriptions)
PEER_BYTES = 64 * 1024
#: unread bytes from one peer that only a flood leaves (a subscriber's few subscriptions are read at once)
BACKLOG_BYTES = 4096
#: subscription messages ZeroMQ queues from one peer before it stops reading that peer's socket
RCVHWM = 64
#: bytes a peer's message may have beyond the longest subscription we serve (ZMTP command framing,
#: the NULL handshake's metadata); with CurveZMQ at least CURVE_MESSAGE (its handshake commands)
MESSAGE_SLACK = 96
CURVE_MESSAGE = 1024
CUT_LOG_S = 5.0   # at most one line per this many seconds about cut peers (after the first 3)
_TCP_INFO_BYTES_RECEIVED = 128   # offset of tcpi_bytes_received (u64) in Linux's struct tcp_info
log = logging.getLogger("mocapgraph.bus")
_GUARDS = itertools.count()   # one monitor address per guard in this process


def limit_inbound(pub: zmq.Socket, longest_key: int, curve: bool) -> None:
    """Set the XPUB options the guard relies on (before bind): a short receive queue, and no
    message longer than a subscription to our longest topic key (``longest_key`` bytes) can be:
    ZeroMQ drops a peer that sends one before its subscription is stored anywhere."""
    pub.setsockopt(zmq.RCVHWM, RCVHWM)
    limit = 1 + longest_key + MESSAGE_SLACK
    pub.setsockopt(zmq.MAXMSGSIZE, max(limit, CURVE_MESSAGE) if curve else limit)


def _flooding(fd: int) -> tuple[str, int, int] | None:
    """(peer, bytes received in all (0: not known), bytes unread) of a connection past the bounds, else None."""
    try:
        s = socket.socket(fileno=os.dup(fd))
    except OSError:
        return None
    try:
        unread = struct.unpack("i", fcntl.ioctl(s.fileno(), termios.FIONREAD, b"\0\0\0\0"))[0]
        total = 0
        if s.family in (socket.AF_INET, socket.AF_INET6):
            info = s.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 256)
            if len(info) >= _TCP_INFO_BYTES_RECEIVED + 8:
                total = struct.unpack_from("<Q", info, _TCP_INFO_BYTES_RECEIVED)[0]
        if total <= PEER_BYTES and unread <= BACKLOG_BYTES:
            return None
        name = s.getpeername()
        peer = "%s:%s" % name[:2] if isinstance(name, tuple) else f"ipc peer (fd {fd})"
        s.shutdown(socket.SHUT_RDWR)   # the connection itself: ZeroMQ sees it end
        return peer, total, unread
    except OSError:
        return None
    finally:
        s.close()   # our duplicate only


def _monitor_event(frames: list[bytes]) -> tuple[int, int]:
    """(event, value) of one monitor message; (0, 0) for one that is not ZeroMQ's v1 form.

    Parsed here rather than with ``zmq.utils.monitor``, whose import pulls in ``zmq.asyncio`` and
    with it asyncio: a node's start-up would pay for an event loop it never runs."""
    if not frames or len(frames[0]) < 6:
        return 0, 0
    return struct.unpack_from("<HI", frames[0])


def give_back_heap() -> None:
    """Return freed heap to the system (glibc keeps it otherwise: RSS would not fall)."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):   # not glibc: the memory is reused, not returned
        pass


class PeerGuard:
    """The accepted connections of one XPUB (from its monitor socket) and the cut of floods.

    ``later``: schedules a one-shot callback (giving the heap back once ZeroMQ freed the peer).
    """

    def __init__(self, pub: zmq.Socket, later: Callable[[float, Callable[[], None]], object]) -> None:
        # an address of our own: pyzmq's default names it after the socket's descriptor, which a
        # node of the same process may get again while the closed socket's monitor still holds it
        self._pub = pub
        self.monitor = pub.get_monitor_socket(zmq.EVENT_ACCEPTED | zmq.EVENT_DISCONNECTED | zmq.EVENT_CLOSED,
                                              addr=f"inproc://peer-guard-{os.getpid()}-{next(_GUARDS)}")
        self._later = later
        self.fds: set[int] = set()
        self.cut = 0
        self._logged = -CUT_LOG_S

    def on_monitor(self) -> None:
        """Track accepted and closed connections (the monitor socket is readable)."""
        while True:
            try:
                event, fd = _monitor_event(self.monitor.recv_multipart(zmq.NOBLOCK))
            except zmq.Again:
                return
            if event == zmq.EVENT_ACCEPTED:
                self.fds.add(fd)
            elif event:
                self.fds.discard(fd)

    def check(self) -> None:
        """Shut down every connection past the bounds (called when unserved subscriptions arrive)."""
        self.on_monitor()
        for fd in list(self.fds):
            found = _flooding(fd)
            if found is None:
                continue
            self.fds.discard(fd)
            self.cut += 1
            self._log(*found)
            self._later(0.2, give_back_heap)

    def _log(self, peer: str, total: int, unread: int) -> None:
        now = time.monotonic()
        if self.cut <= 3 or now - self._logged >= CUT_LOG_S:
            self._logged = now
            log.warning("publisher: cut off subscriber %s: a flood of subscriptions (%s%d bytes unread; bounds %d "
                        "in all, %d unread; %d peer(s) cut so far)", peer,
                        f"{total} bytes sent, " if total else "", unread, PEER_BYTES, BACKLOG_BYTES, self.cut)

    def close(self) -> None:
        try:
            self._pub.disable_monitor()
        except zmq.ZMQError:   # the publisher is closed already
            pass
        self.monitor.close(0)
