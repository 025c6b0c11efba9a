"""Qualisys QTM real-time reader node: labelled and unlabelled markers, 6DOF bodies and a skeleton
from QTM's RT server over TCP (frames optionally as UDP datagrams).

The conversation is :class:`mocapgraph.formats.qtm_session.QTMSession` (version negotiation,
parameter XML, StreamFrames) over our own decoder (:mod:`mocapgraph.formats.qtm_rt`); this node
owns the non-blocking socket on the bus's event loop, the deadlines and the reconnection. It
never blocks: connecting, waiting for QTM's greeting and for each answer are bounded by
``answer_timeout_s``; a QTM that is absent, refuses, never answers or goes away (restart, cable)
is one log line, a state in ``reader_status`` and a retry with doubling back-off from
``reconnect_s`` to ``reconnect_max_s``. Each loss is counted once (``disconnects``).
"""
from __future__ import annotations

import errno
import re
import socket
import time
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..bus.diagnostics import ClockRecord, device_clock
from ..formats import qtm_rt as q
from ..formats.device_file import DeviceConfig, DeviceConfigError, device_or_default
from ..formats.qtm_session import QTMSession, QTMToWorld, SessionEvent
from ..messages import MarkerFrame, RigidBodyFrame, RigidBodyLayout, SkeletonInfo, SkeletonPose
from ..messages.clock_sync import ClockSync
from .marker_source import UP_AXIS_CHOICES, MarkerSourceNode
from .source_base import INPUT_ERRORS

RESYNC_S = 0.5
READ_CHUNK = 1 << 20


class QTMLink(MarkerSourceNode):
    """The connection half of the QTM reader: the socket on the event loop, the session, deadlines,
    back-off and reconnection (see module doc); what the events mean is the subclass's ``_handle``."""

    host = Param("127.0.0.1", "address of the computer running QTM")
    port = Param(22223, "QTM RT port: base port + 1 (little-endian), 22223 by default", minimum=1, maximum=65535)
    version = Param("1.25", "RT protocol version to ask QTM for (1.19 or later)")
    frequency = Param(0.0, "frames per second to ask for; 0 = every frame QTM processes (AllFrames)", minimum=0.0)
    udp_port = Param(0, "0 = frames over the TCP connection; else QTM sends them as UDP datagrams to this "
                        "port of this computer (lower latency, losses possible)", minimum=0, maximum=65535)
    answer_timeout_s = Param(2.0, "longest wait for QTM to connect, greet or answer, s", minimum=0.1)
    reconnect_s = Param(0.2, "first wait before reconnecting, s (doubles up to reconnect_max_s)", minimum=0.01)
    reconnect_max_s = Param(1.0, "longest wait between reconnection attempts, s", minimum=0.01)

    @classmethod
    def graph_check(cls, params: dict[str, Any]) -> None:
        """The graph check refuses a protocol version QTM could not be asked for."""
        from ..bus.node import NodeConfigError

        v = str(params.get("version", "1.25"))
        if not re.fullmatch(r"1\.\d{1,2}", v):
            raise NodeConfigError(f"parameter 'version': {v!r} is not a QTM RT protocol version (e.g. '1.25')")

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.endpoint = f"{self.host}:{self.port}"
        self.sock: socket.socket | None = None
        self.udp: socket.socket | None = None
        self.session: QTMSession | None = None
        self._deadline = None
        self._retry = None
        self._backoff = self.reconnect_s
        self.clock = ClockSync(reset_s=RESYNC_S)   # QTM's frame clock (µs) onto ours
        self._last_frame: int | None = None
        self.counts = dict(frames=0, device_gaps=0, bad_packets=0, count_mismatches=0, disconnects=0,
                           connect_attempts=0, no_more_data=0, clock_resyncs=0, restarts=0, refusals=0)

    # ----- connection ---------------------------------------------------------------------------
    def on_start(self) -> None:
        if self.udp_port:
            udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            try:
                udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 22)
                udp.bind(("0.0.0.0" if self.host not in ("127.0.0.1", "localhost") else "127.0.0.1", self.udp_port))
            except OSError as exc:
                udp.close()
                self.fail(f"qtm {self.endpoint}: cannot listen on udp port {self.udp_port} ({exc.strerror or exc})")
                return
            udp.setblocking(False)
            self.udp = udp
            self.add_reader(udp.fileno(), self._read_udp)
        self._connect()

    def _connect(self) -> None:
        self._retry = None
        self.counts["connect_attempts"] += 1
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        try:
            rc = sock.connect_ex((self.host, self.port))
        except OSError as exc:          # e.g. a host name that does not resolve
            sock.close()
            self._give_up(f"cannot connect ({exc.strerror or exc})")
            return
        if rc not in (0, errno.EINPROGRESS):
            sock.close()
            self._give_up(f"cannot connect ({errno.errorcode.get(rc, rc)})")
            return
        self.sock = sock
        self.session = QTMSession(self.version, f"Frequency:{self.frequency:g}" if self.frequency else "AllFrames",
                                  self.udp_port)
        self.add_reader(sock.fileno(), self._read_tcp)
        self._arm_deadline("did not greet (is this QTM's little-endian RT port, usually 22223?)")
        if self.state not in ("reconnecting", "waiting"):
            self.set_state("connecting", f"qtm {self.endpoint}")

    def _arm_deadline(self, why: str) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
        self._deadline = self.call_later(self.answer_timeout_s, lambda: self._drop(
            f"{why}: nothing in {self.answer_timeout_s:g} s", lost=False))

    def _give_up(self, why: str) -> None:
        """This attempt failed before streaming: one line (rate-limited), retry with back-off."""
        self.warn_limited("connect", "qtm %s: %s; retrying every %.1f s at most", self.endpoint, why,
                          self.reconnect_max_s, every_s=10.0)
        self.set_state("reconnecting" if self.counts["disconnects"] else "waiting", f"qtm {self.endpoint}: {why}")
        self._retry = self.call_later(self._backoff, self._connect)
        self._backoff = min(self._backoff * 2, self.reconnect_max_s)

    def _close(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        if self.sock is not None:
            self.remove_reader(self.sock.fileno())
            self.sock.close()
            self.sock = None
        self.session = None

    def _drop(self, why: str, lost: bool) -> None:
        """Close the connection; ``lost``: it was streaming (a disconnect, counted once)."""
        self._close()
        self.clock.forget()
        self._last_frame = None
        if lost:
            self.counts["disconnects"] += 1
            self._backoff = self.reconnect_s
            self.log.warning("lost qtm %s (%s); reconnecting (disconnect %d)", self.endpoint, why,
                             self.counts["disconnects"])
            self.set_state("reconnecting", f"qtm {self.endpoint} lost: {why}")
            self._retry = self.call_later(self._backoff, self._connect)
            self._backoff = min(self._backoff * 2, self.reconnect_max_s)
        else:
            self._give_up(why)

    def _read_tcp(self) -> None:
        if self.sock is None:
            return
        try:
            data = self.sock.recv(READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as exc:
            self._drop(exc.strerror or str(exc), lost=self.session.state == "streaming")
            return
        if not data:
            self._drop("connection closed by QTM", lost=self.session.state == "streaming")
            return
        arrival = time.time_ns()
        session = self.session
        try:
            events = session.receive(data)
        except q.QTMError as exc:
            self._drop(str(exc), lost=session.state == "streaming")
            return
        out = session.take_outgoing()
        if out:
            try:
                self.sock.sendall(out)      # a few short commands: the kernel buffer takes them
            except OSError as exc:
                self._drop(exc.strerror or str(exc), lost=False)
                return
            if session.state != "streaming":
                self._arm_deadline(f"did not answer in state '{session.state}'")
        self._handle(events, arrival)

    def _read_udp(self) -> None:
        for _ in range(1024):
            try:
                data = self.udp.recv(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                self.warn_limited("udp", "qtm %s: udp: %s", self.endpoint, exc)
                return
            if self.session is not None and self.session.state == "streaming":
                self._handle(self.session.datagram(data), time.time_ns())

    def _handle(self, events: list[SessionEvent], arrival_ns: int) -> None:
        raise NotImplementedError

    def on_stop(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
        self._close()
        if self.udp is not None:
            self.remove_reader(self.udp.fileno())
            self.udp.close()
            self.udp = None


class QTMReader(QTMLink):
    """Streams from a Qualisys QTM RT server (``host``:``port``, the little-endian port, 22223 by
    default) and publishes ``markers`` + latched ``marker_layout`` (labels from QTM's parameter XML),
    ``unlabelled_markers``, ``rigid_bodies`` + latched ``rigid_body_layout`` (QTM's 6DOF bodies) and
    ``skeleton_pose`` + latched ``skeleton_info`` (one QTM skeleton). QTM's millimetres become
    metres; QTM's up axis (``AxisUpwards``) becomes world Z unless ``up_axis`` or a device file
    says otherwise. Unseen markers and untracked bodies are NaN with quality 0.
    """

    summary = "Qualisys QTM real-time server (TCP, or UDP frames): markers, 6DOF bodies, skeleton"
    skeleton = Param("", "which QTM skeleton to publish on skeleton_pose ('' = the first)")
    device = Param("", "device configuration (graph_configs/devices name or path) to move QTM's frame "
                       "in the room: to_world; '' = QTM's frame with its up axis made world Z")
    up_axis = Param("auto", "the QTM axis that points up, made world Z: 'auto' = the device file's to_world.up, "
                            "else QTM's own (The_3D/AxisUpwards); or x, y, z with an optional sign",
                    choices=UP_AXIS_CHOICES)
    unlabelled_markers = Output("unlabelled_markers", MarkerFrame, "QTM's unidentified markers this frame "
                                "(m, world; their count varies; residual NaN)")
    rigid_bodies = Output("rigid_bodies", RigidBodyFrame, "QTM 6DOF bodies in rigid_body_layout order: origin "
                          "(m, world), orientation (wxyz, world), QTM residual as error (m); NaN and quality 0 "
                          "when not tracked")
    rigid_body_layout = Output("rigid_body_layout", RigidBodyLayout, "latched: the 6DOF body names (ids: QTM's "
                               "body numbers from 1, no parents)")
    skeleton_pose = Output("skeleton_pose", SkeletonPose, "segment origins (m, world) and orientations (wxyz, "
                           "world) of one QTM skeleton, skeleton_info order")
    skeleton_info = Output("skeleton_info", SkeletonInfo, "latched: segment names, parents and offsets")

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        self.dev = DeviceConfig()
        self.world = QTMToWorld(self.dev)
        self.qtm: q.QTMParameters | None = None
        self._layout_key: tuple | None = None
        self._skeleton_index = -1
        self.last_arrival = 0.0
        self.last_timecode = ""

    def _handle(self, events: list[SessionEvent], arrival_ns: int) -> None:
        for ev in events:
            if self.session is None:
                return
            if ev.kind == "frame":
                self._frame(ev.value, arrival_ns)
            elif ev.kind == "parameters":
                self._parameters(ev.value)
            elif ev.kind == "bad_packet":
                self.counts["bad_packets"] += 1
                self.warn_limited("bad", "qtm %s: packet skipped: %s", self.endpoint, ev.value)
            elif ev.kind == "no_more_data":
                self.counts["no_more_data"] += 1
                self._last_frame = None
                self.clock.forget()
                self.log.info("qtm %s: no measurement running (no more data); waiting for one", self.endpoint)
                self.set_state("waiting", f"qtm {self.endpoint}: no measurement running")
            elif ev.kind == "refused":
                self.counts["refusals"] += 1
                self._drop(f"QTM refused: {ev.value}", lost=False)
            elif ev.kind == "error":
                self.warn_limited("error", "qtm %s: QTM says: %s", self.endpoint, ev.value)
            elif ev.kind == "event" and ev.value == q.EVENT_QTM_SHUTTING_DOWN:
                self.log.info("qtm %s: QTM is shutting down", self.endpoint)

    # ----- parameters -> latched layouts ----------------------------------------------------------
    def _parameters(self, p: q.QTMParameters) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None
        self._backoff = self.reconnect_s
        try:
            up = self.up_axis if self.up_axis not in ("auto", "") else None
            dev = device_or_default(self.device, up)
            if up is None and not dev.up:
                dev = dev.with_up_axis(p.axis_upwards)
        except (DeviceConfigError, ValueError) as exc:
            self.fail(f"qtm {self.endpoint}: {exc}")
            return
        key = (tuple(p.labels), tuple(p.bodies), tuple((s.name, tuple(s.segment_names)) for s in p.skeletons),
               p.axis_upwards)
        self.qtm, self.dev, self.world = p, dev, QTMToWorld(dev)
        if key != self._layout_key:
            self._layout_key = key
            note = f"QTM millimetres -> m; QTM up axis {p.axis_upwards}; {dev.describe()}"
            try:
                self.bind_layout(p.labels, note, f"qtm {self.endpoint}")
            except INPUT_ERRORS as exc:
                self.fail(f"qtm {self.endpoint}: {exc}")
                return
            nb = len(p.bodies)
            self.rigid_body_layout.publish(RigidBodyLayout(names=p.bodies, ids=np.arange(1, nb + 1, dtype=np.int32),
                                                           parent=np.full(nb, -1, np.int32), units_note=note,
                                                           source=f"qtm {self.endpoint}"))
            self._bind_skeleton(p, note)
            self.log.info("qtm %s: protocol %s, %d labelled markers, %d bodies, %d skeletons at %g Hz",
                          self.endpoint, p.version or self.version, len(p.labels), len(p.bodies),
                          len(p.skeletons), p.frequency)
        self.set_state("streaming", f"qtm {self.endpoint}, protocol {p.version or self.version}, "
                                    f"{'udp' if self.udp_port else 'tcp'}")

    def _bind_skeleton(self, p: q.QTMParameters, note: str) -> None:
        names = [s.name for s in p.skeletons]
        self._skeleton_index = -1
        if not names:
            return
        if self.skeleton and self.skeleton not in names:
            self.warn_limited("skeleton", "qtm %s: no skeleton %r (QTM has %s)", self.endpoint, self.skeleton,
                              ", ".join(names))
            return
        self._skeleton_index = names.index(self.skeleton) if self.skeleton else 0
        sk = p.skeletons[self._skeleton_index]
        offsets = np.nan_to_num(sk.offsets_mm) * 0.001
        self.skeleton_info.publish(SkeletonInfo(source=f"qtm skeleton {sk.name}", joint_names=sk.segment_names,
                                                joint_parent=np.asarray(sk.parents, np.int32),
                                                rest_offsets=offsets, units_note=note))

    # ----- frames ---------------------------------------------------------------------------------
    def stamp_capture(self, device_us: int, arrival_ns: int) -> int:
        """QTM's frame time stamp (µs) -> our clock through :class:`ClockSync` (offset and drift
        followed by minimum-delay filtering; a clock that goes back or jumps, a restart, re-seeds it
        and is counted in ``clock_resyncs``). The one place frames are stamped."""
        capture = self.clock.update(device_us * 1000, arrival_ns)
        self.counts["clock_resyncs"] = self.clock.resets
        return capture

    def _frame(self, f: q.QTMFrame, arrival_ns: int) -> None:
        if self.qtm is None:
            return
        if self._last_frame is not None:
            step = f.frame_number - self._last_frame
            if step > 1:
                self.counts["device_gaps"] += step - 1
            elif step <= 0:
                self.counts["restarts"] += 1
                self.log.info("qtm %s: frame numbers started over (%d after %d): a new measurement",
                              self.endpoint, f.frame_number, self._last_frame)
        self._last_frame = f.frame_number
        capture = self.stamp_capture(f.timestamp_us, arrival_ns)
        rate = self.qtm.frequency
        if f.markers is not None and self.lmap is not None:
            if self._agrees(len(f.markers), self.lmap.n_source, "labelled markers", f.frame_number):
                res = f.marker_residuals if f.marker_residuals is not None else np.full(len(f.markers), np.nan)
                pos = self.lmap.positions(self.world.points(f.markers))
                self.publish_frame(f.frame_number, rate, pos, capture,
                                   residual=self.lmap.values(res.astype(np.float32) * 0.001, np.nan).astype(np.float32))
        if f.unlabelled is not None:
            u = self.world.points(f.unlabelled)
            self.unlabelled_markers.publish(MarkerFrame(
                frame_number=f.frame_number, rate_hz=rate, positions=u, valid=~np.isnan(u).any(axis=1),
                residual=np.full(len(u), np.nan, np.float32)), capture_ns=capture)
        if f.body_positions is not None and f.body_rotations is not None:
            if self._agrees(len(f.body_positions), len(self.qtm.bodies), "6DOF bodies", f.frame_number):
                self._bodies(f, capture)
        if f.skeletons is not None and 0 <= self._skeleton_index < len(f.skeletons):
            self._skeleton(f, capture)
        if f.timecodes is not None:
            smpte = f.timecodes[f.timecodes["type"] == q.TIMECODE_SMPTE]
            if len(smpte):
                self.last_timecode = q.smpte_text(int(smpte["hi"][0]))
        self.counts["frames"] += 1
        self.last_arrival = time.monotonic()

    def _agrees(self, got: int, want: int, what: str, frame: int) -> bool:
        """A frame's item count against the parameters' (else counted, logged, skipped)."""
        if got == want:
            return True
        self.counts["count_mismatches"] += 1
        self.warn_limited("count", "qtm %s: frame %d has %d %s, the parameters %d: skipped", self.endpoint,
                          frame, got, what, want)
        return False

    def _skeleton(self, f: q.QTMFrame, capture: int) -> None:
        sk = f.skeletons[self._skeleton_index]
        sdef = self.qtm.skeletons[self._skeleton_index]
        if not self._agrees(len(sk.ids), len(sdef.segment_names), "skeleton segments", f.frame_number):
            return
        pos = self.world.points(sk.positions)
        quat = self.world.segment_quats(sk.quats_xyzw)
        ok = np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1)
        self.skeleton_pose.publish(SkeletonPose(source_id=sdef.name, frame_number=f.frame_number,
                                                joint_positions=pos, joint_orientations=quat,
                                                tracking_state=np.where(ok, 2, 0).astype(np.int8)),
                                   capture_ns=capture)

    def _bodies(self, f: q.QTMFrame, capture: int) -> None:
        pos = self.world.points(f.body_positions)
        quat = self.world.body_quats(f.body_rotations)
        ok = np.isfinite(pos).all(axis=1) & np.isfinite(quat).all(axis=1)
        pos[~ok] = np.nan
        quat[~ok] = np.nan
        res = (f.body_residuals * 0.001 if f.body_residuals is not None
               else np.full(len(pos), np.nan)).astype(np.float32)
        self.rigid_bodies.publish(RigidBodyFrame(frame_number=f.frame_number, positions=pos, orientations=quat,
                                                 error=np.where(ok, res, np.nan).astype(np.float32),
                                                 quality=np.where(ok, 2, 0).astype(np.int8)), capture_ns=capture)

    # ----- reporting ------------------------------------------------------------------------------
    def status_data(self) -> dict[str, Any]:
        d = dict(self.counts)
        d.update(session=self.session.state if self.session else "closed", timecode=self.last_timecode,
                 rate_hz=self.qtm.frequency if self.qtm else 0.0, clock=self.clock.stats().as_dict(),
                 last_frame_age_s=(time.monotonic() - self.last_arrival) if self.last_arrival else None)
        return d

    def clock_records(self) -> list[ClockRecord]:
        return super().clock_records() + device_clock(f"qtm:{self.endpoint}", self.clock)

    def device_edges(self) -> list[dict[str, Any]]:
        return [{"topic": f"qtm:{self.endpoint}", "sender": "qtm", "rate_hz": self.qtm.frequency if self.qtm else 0.0,
                 "received": self.counts["frames"], "gaps": self.counts["device_gaps"],
                 "rejected": self.counts["bad_packets"] + self.counts["count_mismatches"]}]
