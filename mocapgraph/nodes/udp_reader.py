"""UDP marker stream node: datagrams of the wire protocol (one frame per datagram), so a device
bridge on another machine can feed a graph."""
from __future__ import annotations

import socket
import time
from typing import Any

from ..bus import Param
from .device_stream import WireDeviceSource

MAX_DATAGRAMS_PER_TURN = 1024


class UDPReader(WireDeviceSource):
    """Receives marker frames as UDP datagrams on ``bind``:``port`` and publishes ``markers`` +
    latched ``marker_layout``. Each datagram holds one frame of the binary wire protocol (the
    serial binary format; ``protocol: text`` takes one text line per datagram instead). Bad or
    truncated datagrams and datagrams from hosts other than ``allow_from`` are counted and logged
    (rate-limited), never fatal. A port that cannot be bound is a one-line error (exit 1).
    """

    summary = "marker frames as UDP datagrams (binary wire protocol) from a device bridge"
    bind = Param("127.0.0.1", "address to listen on; 0.0.0.0 for a bridge on another machine")
    port = Param(9870, "UDP port to listen on", minimum=1, maximum=65535)
    protocol = Param("binary", "wire protocol of each datagram: 'binary' or 'text'", choices=("binary", "text"))
    allow_from = Param("", "accept datagrams only from this IP address ('' = from anyone)")

    def wire_protocol(self) -> str:
        return self.protocol

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.endpoint = f"{self.bind}:{self.port}"
        self.sock: socket.socket | None = None
        self.datagrams = 0
        self.foreign = 0

    def on_start(self) -> None:
        if not self.start_layout():
            return
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
            sock.bind((self.bind, self.port))
        except OSError as exc:
            sock.close()
            self.fail(f"udp {self.endpoint}: cannot listen ({exc.strerror or exc})")
            return
        sock.setblocking(False)
        self.sock = sock
        self.watch_fd(sock.fileno())
        self.log.info("listening on udp %s (%s protocol)", self.endpoint, self.protocol)
        self.set_state("streaming", f"udp {self.endpoint}, {self.protocol} protocol")

    def read_device(self) -> None:
        for _ in range(MAX_DATAGRAMS_PER_TURN):
            try:
                data, (host, _port) = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:  # e.g. ICMP errors surfacing on Linux: not fatal for a listener
                self.warn_limited("recv", "udp %s: %s", self.endpoint, exc)
                return
            self.datagrams += 1
            if self.allow_from and host != self.allow_from:
                self.foreign += 1
                self.warn_limited("foreign", "udp %s: datagram from %s ignored (allow_from %s)",
                                  self.endpoint, host, self.allow_from)
                continue
            self.handle_bytes(data, time.time_ns(), end_of_message=True)

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d.update(datagrams=self.datagrams, foreign_datagrams=self.foreign)
        return d

    def on_stop(self) -> None:
        super().on_stop()
        if self.sock is not None:
            self.sock.close()
