"""A QTM RT client conversation without sockets: bytes from QTM in, events and commands to send out.

The ``qtm_reader`` node owns the socket and the timers; this class only knows the protocol's
order of business, as Qualisys documents it: QTM greets ("QTM RT Interface connected"), the
client sends ``Version``, waits for "Version set to ...", asks ``GetParameters General 3D 6D
Skeleton``, and on the XML sends ``StreamFrames`` for the components the parameters make useful
(3D with residuals and unlabelled markers always; 6D with residuals when there are bodies; global
skeletons when there are skeletons; timecode). When QTM says a capture, an RT-from-file playback
or the camera settings changed (event packets), the parameters are asked for again, since labels,
bodies and skeletons may have changed with them.

Events (``kind``, ``value``): ``parameters`` (QTMParameters), ``frame`` (QTMFrame), ``bad_packet``
(the one-line fault of a data packet skipped), ``no_more_data``, ``event`` (QTM's event code),
``refused`` (an error packet answering our Version, GetParameters or StreamFrames: the text) and
``error`` (an unsolicited error packet). A broken stream raises :class:`QTMError`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..kinematics.quaternion import matrix_to_quat, quat_multiply
from . import qtm_rt as q
from .device_file import DeviceConfig

REPARAMETER_EVENTS = (q.EVENT_CAPTURE_STARTED, q.EVENT_RT_FROM_FILE_STARTED, 11)   # 11: camera settings changed


@dataclass
class SessionEvent:
    kind: str
    value: Any = None


class QTMSession:
    """One connection's conversation (see module doc). ``udp_port`` > 0 asks QTM to stream the
    frames as UDP datagrams to that port of this host (feed them to :meth:`datagram`)."""

    def __init__(self, version: str = "1.25", frames: str = "AllFrames", udp_port: int = 0,
                 max_packet: int = q.MAX_PACKET_BYTES) -> None:
        self.version = version
        self.frames = frames
        self.udp_port = int(udp_port)
        self.splitter = q.PacketSplitter(max_packet)
        self.state = "welcome"
        self.out = bytearray()
        self.parameters: q.QTMParameters | None = None
        self.streaming_components: list[str] = []
        self.server_says = ""

    def _send(self, text: str) -> None:
        self.out += q.encode_string(q.PACKET_COMMAND, text)

    def take_outgoing(self) -> bytes:
        data, self.out = bytes(self.out), bytearray()
        return data

    def _components(self, p: q.QTMParameters) -> list[str]:
        comps = ["3DRes", "3DNoLabels"]
        if p.bodies:
            comps.append("6DRes")
        if p.skeletons:
            comps.append("Skeleton:Global")
        return comps + ["Timecode"]

    def receive(self, data: bytes) -> list[SessionEvent]:
        """Bytes from the TCP connection -> events; QTMError when the stream cannot be followed."""
        events: list[SessionEvent] = []
        for ptype, payload in self.splitter.feed(data):
            self._packet(ptype, payload, events)
        return events

    def datagram(self, data: bytes) -> list[SessionEvent]:
        """One UDP datagram (a whole packet) -> events; a bad datagram is one ``bad_packet``."""
        if len(data) < q.HEADER.size:
            return [SessionEvent("bad_packet", f"QTM RT: datagram of {len(data)} bytes")]
        size, ptype = q.HEADER.unpack_from(data, 0)
        if size != len(data):
            return [SessionEvent("bad_packet", f"QTM RT: datagram of {len(data)} bytes says {size}")]
        events: list[SessionEvent] = []
        self._packet(ptype, data[q.HEADER.size:], events)
        return events

    def _packet(self, ptype: int, payload: bytes, events: list[SessionEvent]) -> None:
        if ptype == q.PACKET_DATA:
            if self.state == "streaming":
                try:
                    events.append(SessionEvent("frame", q.decode_data(payload)))
                except q.QTMError as exc:
                    events.append(SessionEvent("bad_packet", str(exc)))
        elif ptype == q.PACKET_COMMAND:
            self._command(q.packet_text(payload))
        elif ptype == q.PACKET_XML:
            try:
                self.parameters = q.parse_parameters(payload)
            except q.QTMError as exc:
                events.append(SessionEvent("refused", str(exc)))
                return
            events.append(SessionEvent("parameters", self.parameters))
            if self.state == "parameters":
                self.streaming_components = self._components(self.parameters)
                udp = f" UDP:{self.udp_port}" if self.udp_port else ""
                self._send(f"StreamFrames {self.frames}{udp} {' '.join(self.streaming_components)}")
                self.state = "streaming"
        elif ptype == q.PACKET_NO_MORE_DATA:
            events.append(SessionEvent("no_more_data"))
        elif ptype == q.PACKET_EVENT:
            code = payload[0] if payload else -1
            events.append(SessionEvent("event", code))
            if code in REPARAMETER_EVENTS and self.state == "streaming":
                self._send("GetParameters General 3D 6D Skeleton")
        elif ptype == q.PACKET_ERROR:
            text = q.packet_text(payload)
            events.append(SessionEvent("refused" if self.state in ("version", "parameters") else "error", text))
        else:
            events.append(SessionEvent("bad_packet", f"QTM RT: packet of unknown type {ptype} skipped"))

    def _command(self, text: str) -> None:
        if self.state == "welcome" and text.startswith("QTM RT Interface connected"):
            self._send(f"Version {self.version}")
            self.state = "version"
        elif self.state == "version" and text.startswith("Version set to"):
            self.server_says = text
            self._send("GetParameters General 3D 6D Skeleton")
            self.state = "parameters"


# ----- QTM's millimetres and axes -> the world (metres, Z up), vectorised -----------------------------
class QTMToWorld:
    """QTM's millimetres and axes -> world metres and wxyz quaternions, for one device transform.

    Precomputed once per parameter set; plain numpy via :mod:`mocapgraph.kinematics.quaternion`
    (scipy's Rotation costs 0.2-0.5 ms a call, a live frame's budget). NaN rows stay NaN.
    """

    def __init__(self, dev: DeviceConfig) -> None:
        self.rot = np.asarray(dev.rotation, dtype=np.float64)
        self.R = self.rot * 0.001                                           # mm -> m folded in
        self.t = np.asarray(dev.translation, dtype=np.float64)
        self.turn = not np.array_equal(dev.rotation, np.eye(3))
        self.quat = matrix_to_quat(np.asarray(dev.rotation, dtype=np.float64))

    def points(self, mm: np.ndarray) -> np.ndarray:
        """Positions [N, 3] mm, QTM axes -> m, world."""
        return mm @ self.R.T + self.t

    def body_quats(self, rot9: np.ndarray) -> np.ndarray:
        """6D rotation matrices [B, 9] (column-major, QTM axes) -> wxyz [B, 4], world."""
        out = np.full((rot9.shape[0], 4), np.nan)
        ok = np.isfinite(rot9).all(axis=1)
        if ok.any():
            R = rot9[ok].reshape(-1, 3, 3).transpose(0, 2, 1).astype(np.float64)
            out[ok] = matrix_to_quat(self.rot @ R if self.turn else R)
        return out

    def segment_quats(self, qxyzw: np.ndarray) -> np.ndarray:
        """Skeleton quaternions [S, 4] x y z w (QTM axes) -> w x y z, world."""
        wxyz = np.asarray(qxyzw, dtype=np.float64)[:, [3, 0, 1, 2]]
        return quat_multiply(self.quat, wxyz) if self.turn else wxyz
