"""Replays a captured QTM real-time session (pcapng, TCP) to a reader as QTM sent it, at its original timing.

:func:`capture_qtm` reassembles what the QTM server sent on its TCP port (segments in sequence
order, retransmissions dropped) and splits it into QTM RT packets: the parameters XML QTM
answered with, and the data packets with the capture time of the segment that completed each.
:class:`QTMReplayServer` is a QTM RT server holding those bytes: the welcome string, ``Version``
(any protocol version the capture's client could have asked), ``QTMVersion``, ``ByteOrder``,
``GetState``, ``GetParameters`` (the captured XML, whatever parts are asked for) and ``StreamFrames``
over TCP (the captured data packets, unchanged, at their original spacing / ``speed``, then "no
more data"); UDP streaming is refused with QTM's "Parse error". One client at a time.
"""
from __future__ import annotations

import selectors
import socket
import time
from dataclasses import dataclass, field

from ..formats import qtm_rt as q
from .pcapng import read_tcp

QTM_PORT = 22223


@dataclass
class QTMCapture:
    """A QTM session out of a capture: the server's address, its parameters XML, (time s, data packet)."""

    server: tuple[str, int]
    xml: str
    frames: list[tuple[float, bytes]] = field(default_factory=list)


def _server_stream(path, port: int | None):
    """The TCP segments a QTM server sent (its port: ``port``, else the one whose first bytes are
    QTM's welcome), in sequence order without repeats: [(time ns, new bytes)], server address."""
    segs = read_tcp(path)
    by_src: dict[tuple[str, int], list] = {}
    for s in segs:
        if s.payload and (port is None or s.src[1] == port):
            by_src.setdefault(s.src, []).append(s)
    for src, ss in by_src.items():
        ss.sort(key=lambda s: (s.seq, s.time_ns))
        first = ss[0].payload
        if port is None and q.WELCOME.encode() not in first[:64]:
            continue
        out, nxt = [], ss[0].seq
        for s in ss:
            start = (nxt - s.seq) & 0xFFFFFFFF
            if start >= len(s.payload) or start > 0x7FFFFFFF:  # all seen already, or a hole before it
                continue
            out.append((s.time_ns, s.payload[start:]))
            nxt = (s.seq + len(s.payload)) & 0xFFFFFFFF
        return out, src
    return [], None


def capture_qtm(path, port: int | None = None) -> QTMCapture:
    """A pcapng capture of a QTM RT session -> :class:`QTMCapture`. ValueError when it holds none."""
    stream, src = _server_stream(path, port)
    if src is None:
        raise ValueError(f"{path}: no QTM RT server stream (TCP, starting '{q.WELCOME}')"
                         + (f" from port {port}" if port else ""))
    split = q.PacketSplitter(1 << 24)
    xml, frames = "", []
    try:
        for t, data in stream:
            for ptype, payload in split.feed(data):
                if ptype == q.PACKET_XML and not xml:
                    xml = q.packet_text(payload)
                elif ptype == q.PACKET_DATA:
                    frames.append((t / 1e9, q.encode_packet(q.PACKET_DATA, payload)))
    except q.QTMError as exc:
        raise ValueError(f"{path}: the QTM stream from {src[0]}:{src[1]} breaks off: {exc}") from None
    if not xml or not frames:
        raise ValueError(f"{path}: the QTM stream from {src[0]}:{src[1]} holds no parameters XML or no frames")
    return QTMCapture(src, xml, frames)


class QTMReplayServer:
    """The captured session served to one client at a time (see module doc)."""

    def __init__(self, capture: QTMCapture, host: str = "127.0.0.1", port: int = QTM_PORT, speed: float = 1.0) -> None:
        self.capture, self.speed = capture, speed
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind((host, port))
        self.listener.listen(4)
        self.port = self.listener.getsockname()[1]
        self.sent = 0
        self.client: socket.socket | None = None
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.listener, selectors.EVENT_READ)
        self._split = q.PacketSplitter(1 << 16)
        self._t0: float | None = None        # monotonic time streaming began
        self._next = 0                       # index of the next frame to send

    def _send(self, data: bytes) -> None:
        try:
            self.client.sendall(data)
        except OSError:
            self._drop()

    def _drop(self) -> None:
        if self.client is not None:
            self.sel.unregister(self.client)
            self.client.close()
        self.client, self._t0 = None, None
        self._split = q.PacketSplitter(1 << 16)

    def _command(self, text: str) -> None:
        words = text.split()
        cmd, args = (words[0].lower() if words else ""), [w.lower() for w in words[1:]]
        reply = lambda s: self._send(q.encode_string(q.PACKET_COMMAND, s))  # noqa: E731
        if cmd == "version":
            reply(f"Version set to {words[1]}" if len(words) > 1 else "Version is 1.25")
        elif cmd == "qtmversion":
            reply("QTM Version is (replayed capture)")
        elif cmd == "byteorder":
            reply("Byte order is little endian")
        elif cmd == "getstate":
            self._send(q.encode_packet(q.PACKET_EVENT, bytes([q.EVENT_CAPTURE_STARTED])))
        elif cmd == "getparameters":
            self._send(q.encode_string(q.PACKET_XML, self.capture.xml))
        elif cmd == "streamframes" and args[:1] == ["stop"]:
            self._t0 = None
        elif cmd == "streamframes" and args and not any(a.startswith("udp") for a in args):
            self._t0, self._next = time.monotonic(), 0
        elif cmd == "streamframes":
            self._send(q.encode_string(q.PACKET_ERROR, "Parse error"))
        else:
            self._send(q.encode_string(q.PACKET_ERROR, "Command not supported"))

    def _due(self, k: int) -> float:
        t = self.capture.frames[k][0] - self.capture.frames[0][0]
        return self._t0 + (t / self.speed if self.speed > 0 else 0.0)

    def serve(self, until_frames: bool = True, timeout_s: float = 0.0) -> int:
        """Serve until the capture's frames were all sent once (``until_frames``) or ``timeout_s``
        passed (0 = no limit); returns frames sent."""
        end = time.monotonic() + timeout_s if timeout_s else float("inf")
        frames = self.capture.frames
        while time.monotonic() < end and not (until_frames and self._next >= len(frames) and self.sent):
            wait = 0.05 if self._t0 is None else max(0.0, min(0.05, self._due(self._next) - time.monotonic()))
            for key, _ in self.sel.select(wait):
                if key.fileobj is self.listener:
                    self._accept()
                elif self.client is not None:
                    self._read()
            while self._t0 is not None and self.client is not None and self._next < len(frames) \
                    and self._due(self._next) <= time.monotonic():
                self._send(frames[self._next][1])
                self._next += 1
                self.sent += 1
                if self._next == len(frames) and self.client is not None:
                    self._send(q.encode_packet(q.PACKET_NO_MORE_DATA))
        return self.sent

    def _accept(self) -> None:
        sock, _ = self.listener.accept()
        if self.client is not None:       # one at a time: the newcomer is turned away
            sock.close()
            return
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client = sock
        self.sel.register(sock, selectors.EVENT_READ)
        self._send(q.encode_string(q.PACKET_COMMAND, q.WELCOME))

    def _read(self) -> None:
        try:
            data = self.client.recv(65536)
        except OSError:
            data = b""
        try:
            packets = self._split.feed(data) if data else None
        except q.QTMError:
            packets = None
        if packets is None:
            self._drop()
            return
        for ptype, payload in packets:
            if ptype == q.PACKET_COMMAND:
                self._command(q.packet_text(payload).strip())

    def close(self) -> None:
        self._drop()
        self.sel.close()
        self.listener.close()
