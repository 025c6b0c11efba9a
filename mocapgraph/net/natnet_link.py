"""The NatNet client's sockets and command channel: connect, model definitions, keep-alive, reconnect.

No threads and no blocking: the reader's event loop watches :meth:`NatNetLink.sockets` and calls
:meth:`receive` when one is readable, and calls :meth:`tick` a few times a second to send what is
due. What a NatNet client does (OptiTrack's NatNet SDK, PacketClient):

- **Command channel**: a UDP socket bound to an ephemeral port on ``interface``; NAT_CONNECT to
  the server's command port (1510) is answered with NAT_SERVERINFO (the NatNet version frames use,
  the clock rate, the data port and multicast group); then NAT_REQUEST_MODELDEF, answered with
  NAT_MODELDEF; and ``FrameRate``, a NAT_REQUEST answered with a float. Unanswered requests are
  sent again every ``retry_s``; a server that never answers gives ONE warning line, then the
  client keeps retrying quietly (one line a minute), never blocking.
- **Discovery**: with no server address, NAT_DISCOVERY is broadcast to the command port and the
  first server that answers becomes the server.
- **Data**: unicast frames arrive on the command socket (the server sends them to the address
  that connected, kept alive by NAT_KEEPALIVE every ``keepalive_s``); multicast frames on a socket
  bound to the data port that joined the group on ``interface``.
- **Reconnect**: no frame for ``silence_s`` while streaming means the server went away (Motive
  closed, restarted, the cable): one reconnect, counted and logged once, and connecting starts
  over until frames flow again.
- **Arrival times**: each datagram's arrival is the kernel's receive time (``SO_TIMESTAMPNS`` on
  Linux x86-64 / ARM), so a reader held up by a busy machine does not pass its own lag on to the
  clock estimate as network delay; elsewhere (or a stamp not believable) the time it is read.
"""
from __future__ import annotations

import logging
import platform
import socket
import struct
import sys
import time
from dataclasses import dataclass

from ..formats import natnet as nn

NAT_DISCOVERY = 14
RECV_BYTES = 65536
MAX_PER_TURN = 512
#: NatNet version we announce in NAT_CONNECT (servers stream their own; 4.x servers accept it)
CLIENT_VERSION = (4, 1, 0, 0)
#: SO_TIMESTAMPNS (= SCM_TIMESTAMPNS) where Linux's generic socket options apply; Python names it not
SO_TIMESTAMPNS = 35 if sys.platform == "linux" and platform.machine() in ("x86_64", "aarch64", "armv7l") else 0
ANC_BYTES = 64


def kernel_stamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp every datagram ``sock`` receives; whether it will."""
    if not SO_TIMESTAMPNS:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def arrival_ns(ancdata: list, now_ns: int) -> int:
    """The kernel's receive time out of a datagram's ancillary data; ``now_ns`` (the time it was
    read) when there is none or it is not believable (after now, or over 10 s before)."""
    for level, kind, data in ancdata:
        if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= 16:
            sec, nsec = struct.unpack_from("qq", data)
            t = sec * 1_000_000_000 + nsec
            if now_ns - 10_000_000_000 < t <= now_ns:
                return t
    return now_ns


@dataclass
class LinkConfig:
    """Where the server is and how frames reach us."""

    server: str = "127.0.0.1"        # '' = discovery by broadcast
    command_port: int = 1510
    data_port: int = 1511
    multicast_group: str = ""        # '' = unicast (frames on the command socket)
    interface: str = "0.0.0.0"       # local address to bind and to join the group on
    retry_s: float = 1.0
    keepalive_s: float = 1.0
    silence_s: float = 1.0
    discovery_to: str = "255.255.255.255"


class NatNetLink:
    """Sockets and the command channel's state (see module doc)."""

    def __init__(self, cfg: LinkConfig, log: logging.Logger) -> None:
        self.cfg, self.log = cfg, log
        self.server = cfg.server
        self.cmd: socket.socket | None = None
        self.data: socket.socket | None = None
        self.state = "connecting"        # connecting -> streaming -> reconnecting -> streaming ...
        self.have_info = False
        self.need_defs = True
        self.need_rate = True
        self.connect_sent = 0
        self.rate_asked = 0
        self.reconnects = 0
        self.silent_warnings = 0
        self._first_try = 0.0
        self._next_connect = 0.0
        self._next_defs = 0.0
        self._next_keepalive = 0.0
        self._last_warn = -1e9
        self.last_frame = 0.0
        self._stamped: dict[socket.socket, bool] = {}

    @property
    def where(self) -> str:
        return f"{self.server or 'discovery'}:{self.cfg.command_port}"

    # ----- sockets ---------------------------------------------------------------------------
    def open(self) -> None:
        """Bind the sockets (OSError with the reason when the address or port is unusable)."""
        c = self.cfg
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
        self.cmd.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.cmd.bind((c.interface, 0))
        self.cmd.setblocking(False)
        self._stamped = {self.cmd: kernel_stamps(self.cmd)}
        if c.multicast_group:
            d = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.data = d
            d.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            d.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
            d.bind(("", c.data_port))
            iface = c.interface if c.interface not in ("", "0.0.0.0") else "0.0.0.0"
            d.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                         socket.inet_aton(c.multicast_group) + socket.inet_aton(iface))
            d.setblocking(False)
            self._stamped[d] = kernel_stamps(d)

    def sockets(self) -> list[socket.socket]:
        return [s for s in (self.cmd, self.data) if s is not None]

    def close(self) -> None:
        for s in self.sockets():
            try:
                if self.have_info and s is self.cmd and self.server:
                    s.sendto(nn.command(nn.NAT_DISCONNECT), (self.server, self.cfg.command_port))
            except OSError:
                pass
            s.close()
        self.cmd = self.data = None

    def receive(self, sock: socket.socket) -> list[tuple[bytes, tuple[str, int], int]]:
        """Every datagram waiting on ``sock`` (at most MAX_PER_TURN): (bytes, sender, arrival ns)."""
        out = []
        stamped = self._stamped.get(sock, False)
        for _ in range(MAX_PER_TURN):
            try:
                if stamped:
                    data, anc, _flags, addr = sock.recvmsg(RECV_BYTES, ANC_BYTES)
                else:
                    data, addr = sock.recvfrom(RECV_BYTES)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # ICMP port unreachable from a server that is not there
                self.log.debug("natnet %s: %s", self.where, exc)
                break
            now = time.time_ns()
            out.append((data, addr, arrival_ns(anc, now) if stamped else now))
        return out

    def _send(self, packet: bytes, to: tuple[str, int] | None = None) -> None:
        try:
            self.cmd.sendto(packet, to or (self.server, self.cfg.command_port))
        except OSError as exc:  # no route yet, interface down: the next retry tries again
            self.log.debug("natnet %s: send failed: %s", self.where, exc)

    # ----- command channel --------------------------------------------------------------------
    def tick(self, now: float) -> None:
        """Send what is due: connect/discovery, model definition and rate requests, keep-alive;
        notice a silent stream."""
        c = self.cfg
        if self.state == "streaming" and now - self.last_frame > c.silence_s:
            self.reconnects += 1
            self.state = "reconnecting"
            self.have_info, self.need_defs = False, True
            self._first_try = self._next_connect = now
            self.log.warning("natnet %s: no frames for %.1f s (server stopped or restarted?): "
                             "reconnecting (reconnect %d)", self.where, now - self.last_frame, self.reconnects)
        if not self.have_info and now >= self._next_connect:
            if not self._first_try:
                self._first_try = now
            self._connect()
            self._next_connect = now + c.retry_s
            waited = now - self._first_try
            if waited >= 2 * c.retry_s and now - self._last_warn >= (60.0 if self.silent_warnings else 0.0):
                self.silent_warnings += 1
                self._last_warn = now
                self.log.warning("natnet %s: no answer after %.1f s (is Motive running with streaming on, "
                                 "and this the right address?); still trying every %g s",
                                 self.where, waited, c.retry_s)
        if self.have_info and (self.need_defs or self.need_rate) and now >= self._next_defs:
            if self.need_defs:
                self._send(nn.command(nn.NAT_REQUEST_MODELDEF))
            if self.need_rate:
                self.rate_asked += 1
                self.need_rate = self.rate_asked < 3  # servers that do not answer it: measured instead
                self._send(nn.command(nn.NAT_REQUEST, b"FrameRate\0"))
            self._next_defs = now + c.retry_s
        if self.have_info and not c.multicast_group and now >= self._next_keepalive:
            self._send(nn.command(nn.NAT_KEEPALIVE))
            self._next_keepalive = now + c.keepalive_s

    def _connect(self) -> None:
        self.connect_sent += 1
        if self.server:
            self._send(nn.connect_command("mocapgraph", CLIENT_VERSION))
        else:
            body = nn.connect_command("mocapgraph", CLIENT_VERSION)[4:]
            self._send(nn.command(NAT_DISCOVERY, body), (self.cfg.discovery_to, self.cfg.command_port))

    def got_server_info(self, sender: tuple[str, int]) -> None:
        if not self.server:  # a discovery answer: now connect to that server (unicast needs it)
            self.server = sender[0]
            self.log.info("natnet: discovered a server at %s", sender[0])
            self._next_connect = 0.0
            return
        if self.silent_warnings:
            self.log.info("natnet %s: the server answered", self.where)
        self.have_info = True
        self.silent_warnings = 0
        self._first_try = 0.0
        self._next_defs = 0.0

    def request_model_defs(self) -> None:
        """Ask again at the next tick (a frame held an id the definitions lack)."""
        if not self.need_defs:
            self.need_defs = True
            self._next_defs = 0.0

    def got_frame(self, now: float) -> bool:
        """A frame arrived; True when it ends a reconnect (the stream is back)."""
        self.last_frame = now
        back = self.state == "reconnecting"
        self.state = "streaming"
        return back

    def got_response(self, payload: bytes) -> float | None:
        """A NAT_RESPONSE body: the frame rate when it is the 4-byte float answer to FrameRate."""
        if self.rate_asked and len(payload) == 4:
            self.need_rate = False
            rate = struct.unpack("<f", payload)[0]
            return rate if 0 < rate < 100000 else None
        return None
