"""A UDP sender for the outlet nodes: one resolved address, counted sends and failures, logged sparingly.

OSC and VMC outlets send one datagram per frame to a host and port a user configured. A host that
does not resolve is a configuration error (one line, before the node starts); a send that fails at
run time (nobody listening, ICMP refused; the network down) is counted and logged on the 1st, 10th,
100th and every 1000th failure, and the stream goes on.
"""
from __future__ import annotations

import logging
import socket


class HostError(ValueError):
    """The configured host does not resolve (one line)."""


class DatagramOut:
    """Datagrams to ``host``:``port``; ``sent`` and ``send_errors`` count them."""

    def __init__(self, host: str, port: int, log: logging.Logger, what: str) -> None:
        """``what`` names the datagrams in the log ("OSC", "VMC")."""
        try:
            infos = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
        except socket.gaierror as exc:
            raise HostError(f"host {host!r}: {exc.strerror}") from None
        family, _, _, _, self.addr = infos[0]
        self.host, self.port, self.log, self.what = host, port, log, what
        self.sock = socket.socket(family, socket.SOCK_DGRAM)
        self.sent = self.send_errors = 0

    def send(self, data: bytes) -> None:
        """Send one datagram; a failure is counted (and logged sparingly), never raised."""
        try:
            self.sock.sendto(data, self.addr)
            self.sent += 1
        except OSError as exc:   # nobody listening (ICMP refused) or the network is down: keep going
            self.send_errors += 1
            n = self.send_errors
            if n in (1, 10, 100) or n % 1000 == 0:
                self.log.warning("%s send to %s:%d failed (%s); %d so far", self.what, self.host, self.port, exc, n)

    def close(self) -> None:
        self.sock.close()
