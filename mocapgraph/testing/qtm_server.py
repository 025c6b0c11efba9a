"""A simulated Qualisys QTM real-time server: the synthetic actor streamed over the QTM RT protocol.

It is the other end of the ``qtm_reader`` node and of Qualisys's own client ``qtm-rt``, for tests,
benchmarks and trying ``lab_qtm.yaml`` without cameras (``mocapgraph device simulate qtm``). It
speaks what a client of QTM sees on the little-endian port (22223 by default): the welcome
command string, ``Version`` negotiation (1.19 to 1.26), ``QTMVersion``, ``ByteOrder``,
``GetState``, ``GetParameters`` (General, 3D labels, 6D bodies, skeletons), ``GetCurrentFrame``,
``StreamFrames AllFrames | Frequency:n | FrequencyDivisor:n [UDP[:address]:port] <components>``
and ``StreamFrames Stop``, with the components 3D, 3DRes, 3DNoLabels(Res), 6D(Res), 6DEuler(Res),
Skeleton, Skeleton:Global and Timecode (SMPTE and camera time).

What it sends is exactly what a reader should reconstruct (:class:`ActorQTMSource`): the actor's
markers in millimetres in QTM's axes (``axis_up``: ``+Z`` as QTM's default, or another axis), its
first ``n_bodies`` limbs as 6DOF bodies, its limbs as one skeleton, a few unlabelled strays; or
the labelled markers of a C3D or TRC file or of a bag mocapgraph recorded (:class:`TrialQTMSource`);
sources and the delay and drift injector are shared with the NatNet simulator
(:mod:`mocapgraph.testing.sim_sources`).
Faults on demand: frames lost (``loss``, frame numbers jump as when QTM skips), each frame held
back by a random ``delay_ms`` (lo, hi) (TCP keeps the order), QTM's clock running ``drift_ppm``
fast, a malformed data packet every ``bad_every`` frames, a measurement of ``frames`` frames followed by "no more
data", and QTM restarting every ``restart_every_s`` (a shutting-down event, connections closed,
the port closed for ``restart_down_s``, frame numbers starting over).
"""
from __future__ import annotations

import selectors
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from ..formats import qtm_rt as q
from ..formats.device_file import DeviceConfig
from .sim_sources import ActorSource, DelayLine, LinkFaults, RecordedMarkers

SUPPORTED_VERSIONS = tuple(f"1.{m}" for m in range(19, 27))
QTM_VERSION_TEXT = "QTM Version is 2024.2 (build 0) (mocapgraph simulator)"
OUTBUF_LIMIT = 8 << 20


@dataclass
class SourceFrame:
    """One frame as QTM holds it: millimetres, QTM axes (see :class:`ActorQTMSource`)."""

    frame: int
    markers: np.ndarray          # float32[N, 3] mm, NaN where occluded
    residuals: np.ndarray        # float32[N] mm
    unlabelled: np.ndarray       # float32[K, 3] mm
    unlabelled_ids: np.ndarray   # int32[K]
    body_pos: np.ndarray         # float32[B, 3] mm, NaN where not tracked
    body_rot: np.ndarray         # float32[B, 9] column-major
    body_euler: np.ndarray       # float32[B, 3] degrees, intrinsic X-Y-Z (roll, pitch, yaw)
    body_res: np.ndarray         # float32[B] mm
    seg_global: q.Skeleton
    seg_local: q.Skeleton


class ActorQTMSource:
    """The synthetic actor as QTM would measure it.

    ``axis_up``: QTM's up axis (``The_3D/AxisUpwards``); the world is mapped into QTM's axes with
    the inverse of what a reader applies (:meth:`DeviceConfig.with_up_axis`). ``occlude_every`` N
    > 0: on frames k with k % N == 0, marker k % M and body k % B are not seen (NaN), so readers'
    quality flags can be checked.
    """

    def __init__(self, layout: str = "plug_in_gait", rate_hz: float = 120.0, seed: int = 0,
                 noise_mm: float = 0.0, n_bodies: int = 5, axis_up: str = "+Z", n_unlabelled: int = 2,
                 occlude_every: int = 0) -> None:
        self.src = ActorSource(layout, rate_hz, seed, noise_mm)
        self.actor = self.src.actor
        self.rate_hz = self.src.rate_hz
        self.labels = self.src.labels
        self.limb_names = self.src.limb_names
        self.n_bodies = min(int(n_bodies), len(self.limb_names))
        self.body_names = self.limb_names[:self.n_bodies]
        self.limb_parent = self.src.limb_parent
        self.origin_joint = self.src.origin_joint   # segment origin: the joint a limb hangs from
        self.axis_up = axis_up
        self.dev = DeviceConfig().with_up_axis(axis_up)
        self.n_unlabelled = int(n_unlabelled)
        self.occlude_every = int(occlude_every)
        f0 = self.frame(0)
        self.body_points = [np.zeros((3, 3)) + np.eye(3) * 40.0 for _ in self.body_names]
        self.skeleton_def = q.SkeletonDef("actor", self.limb_names, list(range(1, len(self.limb_names) + 1)),
                                          [int(p) for p in self.limb_parent], f0.seg_local.positions.astype(float))

    @property
    def n_frames(self) -> int:
        return self.actor.n_frames

    def to_qtm_points(self, world_m: np.ndarray) -> np.ndarray:
        return (self.dev.points_from_world(world_m) * 1000.0).astype(np.float32)

    def preload(self, start: int, count: int) -> None:
        """Compute frames [start, start + count) now, so serving them costs no CPU (benchmarks)."""
        self._pre = {}
        self._pre = {k: self.frame(k) for k in range(start, start + count)}

    def frame(self, k: int) -> SourceFrame:
        """Frame ``k`` (session frames loop)."""
        pre = getattr(self, "_pre", None)
        if pre and k in pre:
            return pre[k]
        cap, i = self.src.capture_at(k)
        markers = self.to_qtm_points(cap.markers[i])
        R = Rotation.from_quat(cap.limb_quat[i], scalar_first=True).as_matrix()     # world, per limb
        Rq = np.einsum("ba,lbc->lac", self.dev.rotation, R)                           # QTM axes
        origins = self.src.segment_origins(cap.joint_centres[i], cap.limb_centroids[i])
        o = self.to_qtm_points(origins).astype(np.float64)
        B = self.n_bodies
        body_pos = self.to_qtm_points(cap.limb_centroids[i][:B])
        body_rot = Rq[:B].transpose(0, 2, 1).reshape(B, 9).astype(np.float32)   # column-major
        euler = Rotation.from_matrix(Rq[:B]).as_euler("XYZ", degrees=True).astype(np.float32)
        if self.occlude_every and k % self.occlude_every == 0:
            markers[k % len(markers)] = np.nan
            if B:
                body_pos[k % B] = np.nan
                body_rot[k % B] = np.nan
                euler[k % B] = np.nan
        quat_g = Rotation.from_matrix(Rq).as_quat()                                   # x y z w
        par = self.limb_parent
        Rp = np.where((par >= 0)[:, None, None], Rq[np.maximum(par, 0)], np.eye(3))
        op = np.where((par >= 0)[:, None], o[np.maximum(par, 0)], 0.0)
        local_p = np.einsum("lba,lb->la", Rp, o - op)
        local_q = Rotation.from_matrix(np.einsum("lba,lbc->lac", Rp, Rq)).as_quat()
        ids = np.arange(1, len(self.limb_names) + 1, dtype=np.int32)
        t = k / self.rate_hz
        strays = np.array([[1000.0 + 100 * j, -500.0, 20.0 + 10 * np.sin(t + j)] for j in range(self.n_unlabelled)],
                          np.float32).reshape(-1, 3)
        return SourceFrame(
            frame=k, markers=markers, residuals=np.where(np.isnan(markers[:, 0]), np.nan, 0.8).astype(np.float32),
            unlabelled=strays, unlabelled_ids=np.arange(101, 101 + self.n_unlabelled, dtype=np.int32),
            body_pos=body_pos, body_rot=body_rot, body_euler=euler,
            body_res=np.where(np.isnan(body_pos[:, 0]), np.nan, 0.5).astype(np.float32),
            seg_global=q.Skeleton(ids, o.astype(np.float32), quat_g.astype(np.float32)),
            seg_local=q.Skeleton(ids, local_p.astype(np.float32), local_q.astype(np.float32)))

    def parameters(self, version: str, parts: tuple[str, ...]) -> str:
        return q.parameters_xml(version, self.rate_hz, self.axis_up, self.labels,
                                list(zip(self.body_names, self.body_points)), [self.skeleton_def], parts)


class TrialQTMSource:
    """A marker recording (C3D, TRC, or a bag's MarkerFrame ``topic``: see
    :class:`~mocapgraph.testing.sim_sources.RecordedMarkers`) as QTM would stream it: its labels and
    trajectories in millimetres, QTM axes ``axis_up`` (a file's own up axis made world Z first, as
    the readers do); no 6DOF bodies, no skeleton, no unlabelled markers. Frame ``k`` is the
    recording's frame ``k`` (looping)."""

    def __init__(self, path: str, axis_up: str = "+Z", topic: str | None = None) -> None:
        rec = RecordedMarkers(path, topic)
        self.recording = rec
        self.trial = rec.trial
        self.rate_hz = rec.rate_hz
        self.labels = list(rec.labels)
        self.body_names: list[str] = []
        self.axis_up = axis_up
        self.dev = DeviceConfig().with_up_axis(axis_up)
        self.mm = (self.dev.points_from_world(rec.positions) * 1000.0).astype(np.float32)
        self.res = (rec.residuals * 1000.0).astype(np.float32)
        none = q.Skeleton(np.zeros(0, np.int32), np.zeros((0, 3), np.float32), np.zeros((0, 4), np.float32))
        self._empty = dict(unlabelled=np.zeros((0, 3), np.float32), unlabelled_ids=np.zeros(0, np.int32),
                           body_pos=np.zeros((0, 3), np.float32), body_rot=np.zeros((0, 9), np.float32),
                           body_euler=np.zeros((0, 3), np.float32), body_res=np.zeros(0, np.float32),
                           seg_global=none, seg_local=none)

    @property
    def n_frames(self) -> int:
        return self.mm.shape[0]

    def frame(self, k: int) -> SourceFrame:
        i = k % self.n_frames
        return SourceFrame(frame=k, markers=self.mm[i], residuals=self.res[i], **self._empty)

    def parameters(self, version: str, parts: tuple[str, ...]) -> str:
        return q.parameters_xml(version, self.rate_hz, self.axis_up, self.labels, [], [], parts)


def encode_components(f: SourceFrame, comps: tuple[str, ...], rate_hz: float) -> list[bytes]:
    """The components a client asked for (lower-case StreamFrames names), in its order."""
    out = []
    for c in comps:
        if c == "3d":
            out.append(q.component_3d(f.markers))
        elif c == "3dres":
            out.append(q.component_3d(f.markers, f.residuals))
        elif c in ("3dnolabels", "3dnolabelsres"):
            out.append(q.component_3d_no_labels(f.unlabelled, f.unlabelled_ids,
                                                np.full(len(f.unlabelled), 0.3, np.float32) if c.endswith("res") else None))
        elif c in ("6d", "6dres"):
            out.append(q.component_6d(f.body_pos, f.body_rot, f.body_res if c.endswith("res") else None))
        elif c in ("6deuler", "6deulerres"):
            out.append(q.component_6d_euler(f.body_pos, f.body_euler, f.body_res if c.endswith("res") else None))
        elif c == "skeleton":
            out.append(q.component_skeletons([f.seg_local]))
        elif c == "skeleton:global":
            out.append(q.component_skeletons([f.seg_global]))
        elif c == "timecode":
            cam_us = round(f.frame * 1e6 / rate_hz)
            out.append(q.component_timecodes([(q.TIMECODE_SMPTE, q.smpte(f.frame, rate_hz), 0),
                                              (q.TIMECODE_CAMERA, cam_us >> 32, cam_us & 0xFFFFFFFF)]))
    return out


@dataclass
class _Client:
    sock: socket.socket
    addr: tuple
    splitter: q.PacketSplitter = field(default_factory=lambda: q.PacketSplitter(1 << 16))
    version: str = "1.1"
    comps: tuple[str, ...] = ()
    divisor: int = 0                  # 0 = not streaming
    udp_to: tuple | None = None
    outbuf: bytearray = field(default_factory=bytearray)
    later: DelayLine = field(default_factory=lambda: DelayLine(keep_order=True))   # delayed frames (TCP keeps order)


class _Commands:
    """QTM's answers to a client's commands (the server's half of the conversation); the server
    class supplies the sockets (``_send``), the source and the measurement's state."""

    def _command(self, c: _Client, text: str) -> None:
        words = text.split()
        cmd = words[0].lower() if words else ""
        args = [w.lower() for w in words[1:]]
        reply = lambda s: self._send(c, q.encode_string(q.PACKET_COMMAND, s))  # noqa: E731
        error = lambda s: self._send(c, q.encode_string(q.PACKET_ERROR, s))    # noqa: E731
        if cmd == "version":
            if not args:
                reply(f"Version is {c.version}")
            elif words[1] in SUPPORTED_VERSIONS:
                c.version = words[1]
                reply(f"Version set to {c.version}")
            else:
                error("Version NOT supported")
        elif cmd == "qtmversion":
            reply(QTM_VERSION_TEXT)
        elif cmd == "byteorder":
            reply("Byte order is little endian")
        elif cmd == "getstate":
            ev = q.EVENT_CAPTURE_STOPPED if self.measurement_over else q.EVENT_CAPTURE_STARTED
            self._send(c, q.encode_packet(q.PACKET_EVENT, bytes([ev])))
        elif cmd == "getparameters":
            parts = tuple(args) or ("all",)
            known = {"all", "general", "3d", "6d", "skeleton", "skeleton:global"}
            if not set(parts) <= known:
                error("Parameters not available")
            else:
                self._send(c, q.encode_string(q.PACKET_XML, self.source.parameters(c.version, parts)))
        elif cmd == "getcurrentframe":
            if not self._comps_ok(args):
                error("Parse error")
            elif self.measurement_over:
                self._send(c, q.encode_packet(q.PACKET_NO_MORE_DATA))
            else:
                f = self.source.frame(self.frame_k)
                self._send(c, q.encode_data(self.frame_k, self._stamp_us(self.frame_k),
                                            encode_components(f, tuple(args), self.rate_hz)))
        elif cmd == "streamframes":
            self._stream_command(c, args, error)
        elif cmd == "takecontrol":
            reply("You are now master")
        elif cmd == "releasecontrol":
            reply("You are now a regular client")
        else:
            error("Command not supported")

    @staticmethod
    def _comps_ok(comps: list[str]) -> bool:
        return bool(comps) and all(x in q.COMPONENT_NAMES for x in comps)

    def _stream_command(self, c: _Client, args: list[str], error) -> None:
        if args[:1] == ["stop"]:
            c.divisor = 0
            return
        if not args:
            error("Parse error")
            return
        rate, rest = args[0], args[1:]
        try:
            if rate == "allframes":
                divisor = 1
            elif rate.startswith("frequencydivisor:"):
                divisor = max(1, int(rate.split(":")[1]))
            elif rate.startswith("frequency:"):
                divisor = max(1, round(self.rate_hz / max(float(rate.split(":")[1]), 1e-9)))
            else:
                raise ValueError(rate)
            udp_to = None
            if rest and rest[0].startswith("udp"):
                bits = rest[0].split(":")
                port = int(bits[-1])
                udp_to = (bits[1] if len(bits) == 3 else c.addr[0], port)
                rest = rest[1:]
        except (ValueError, IndexError):
            error("Parse error")
            return
        if not self._comps_ok(rest):
            error("Parse error")
            return
        c.comps, c.divisor, c.udp_to = tuple(rest), divisor, udp_to
        if self.measurement_over:
            self._send(c, q.encode_packet(q.PACKET_NO_MORE_DATA))
            c.divisor = 0


class QTMSimServer(_Commands):
    """The server (see module doc). ``serve()`` blocks; ``start()`` runs it in a thread, ``stop()``
    ends it. ``frames`` > 0: the measurement ends after that many frames ("no more data")."""

    def __init__(self, source: ActorQTMSource | TrialQTMSource, host: str = "127.0.0.1", port: int = 22223, loss: float = 0.0,
                 seed: int = 0, frames: int = 0, bad_every: int = 0, restart_every_s: float = 0.0,
                 restart_down_s: float = 1.0, start_frame: int = 0, delay_ms: tuple[float, float] = (0.0, 0.0),
                 drift_ppm: float = 0.0) -> None:
        self.source = source
        self.host, self.port = host, int(port)
        self.rate_hz = source.rate_hz
        self.loss = float(loss)
        self.rng = np.random.default_rng(seed)
        self.frames = int(frames)
        self.bad_every = int(bad_every)
        self.restart_every_s = float(restart_every_s)
        self.restart_down_s = float(restart_down_s)
        self.start_frame = int(start_frame)
        self.sel = selectors.DefaultSelector()
        self.clients: dict[socket.socket, _Client] = {}
        self.listener: socket.socket | None = None
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.sent_frames = 0
        self.lost_frames = 0
        self.bad_sent = 0
        self.lost_log: deque[int] = deque(maxlen=100_000)    # frame numbers lost / sent malformed
        self.bad_log: deque[int] = deque(maxlen=100_000)
        self.link = LinkFaults(delay_ms, drift_ppm, seed)     # the injector the NatNet simulator uses too
        self.delay_ms, self.drift_ppm = self.link.delay_ms, self.link.drift_ppm
        #: (frame number, true capture time on this machine's wall clock, ns): the frame's place in
        #: the measurement's schedule, before any send delay (what a reader's stamps should equal)
        self.capture_log: deque[tuple[int, int]] = deque(maxlen=100_000)
        self.send_log: deque[tuple[int, int]] = deque(maxlen=100_000)   # (frame, wall ns) as it was sent
        self._udp_later = DelayLine()                                   # (packet, address) datagrams
        self._mono0, self._wall0 = time.monotonic(), time.time_ns()
        self._epoch = self._mono0          # monotonic time of the measurement's first frame
        self.restarts = 0
        self.frame_k = self.start_frame
        self._epoch = time.monotonic()
        self._listen()

    # ----- sockets ------------------------------------------------------------------------------
    def _listen(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind((self.host, self.port))
        s.listen(16)
        s.setblocking(False)
        self.port = s.getsockname()[1]
        self.listener = s
        self.sel.register(s, selectors.EVENT_READ, None)

    def _close_all(self) -> None:
        for c in list(self.clients.values()):
            self._drop(c)
        if self.listener is not None:
            self.sel.unregister(self.listener)
            self.listener.close()
            self.listener = None

    def _accept(self) -> None:
        try:
            sock, addr = self.listener.accept()
        except OSError:
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        c = _Client(sock, addr)
        self.clients[sock] = c
        self.sel.register(sock, selectors.EVENT_READ, c)
        self._send(c, q.encode_string(q.PACKET_COMMAND, q.WELCOME))

    def _drop(self, c: _Client) -> None:
        if self.clients.pop(c.sock, None) is not None:
            self.sel.unregister(c.sock)
            c.sock.close()

    def _send(self, c: _Client, data: bytes) -> None:
        c.outbuf += data
        self._flush(c)

    def _flush(self, c: _Client) -> None:
        try:
            while c.outbuf:
                n = c.sock.send(c.outbuf)
                del c.outbuf[:n]
        except (BlockingIOError, InterruptedError):
            if len(c.outbuf) > OUTBUF_LIMIT:   # a client that stopped reading: QTM drops it too
                self._drop(c)
        except OSError:
            self._drop(c)

    def _read(self, c: _Client) -> None:
        try:
            data = c.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self._drop(c)
            return
        try:
            packets = c.splitter.feed(data)
        except q.QTMError:
            self._drop(c)
            return
        for ptype, payload in packets:
            if ptype == q.PACKET_COMMAND:
                self._command(c, q.packet_text(payload).strip())
            elif ptype == q.PACKET_XML:
                self._send(c, q.encode_string(q.PACKET_COMMAND, "Setting parameters failed"))

    # ----- the measurement ------------------------------------------------------------------------
    @property
    def measurement_over(self) -> bool:
        return bool(self.frames) and self.frame_k - self.start_frame >= self.frames

    def _stamp_us(self, k: int) -> int:
        """QTM's time stamp of frame ``k``: µs since the measurement began, by QTM's clock (which
        runs ``drift_ppm`` fast against ours)."""
        return round(self.link.device_s((k - self.start_frame) / self.rate_hz) * 1e6)

    def _due(self, k: int) -> float:
        """Monotonic time frame ``k`` is captured (the measurement's schedule)."""
        return self._epoch + (k - self.start_frame) / self.rate_hz

    def _deliver(self, c: _Client, pkt: bytes) -> None:
        """Send a frame now, or after the injected delay (TCP: never before an earlier frame)."""
        if not self.link.delays:
            if c.udp_to is not None:
                try:
                    self.udp.sendto(pkt, c.udp_to)
                except OSError:
                    pass
            else:
                self._send(c, pkt)
            return
        due = time.monotonic() + self.link.hold_s()
        if c.udp_to is not None:
            self._udp_later.push(due, (pkt, c.udp_to))
        else:
            c.later.push(due, pkt)

    def _release(self) -> float:
        """Send the delayed frames now due; returns when the next one is (inf: none)."""
        now = time.monotonic()
        nxt = float("inf")
        for c in list(self.clients.values()):
            for pkt in c.later.pop_due(now):
                self._send(c, pkt)
            nxt = min(nxt, c.later.next_due)
        for pkt, to in self._udp_later.pop_due(now):
            try:
                self.udp.sendto(pkt, to)
            except OSError:
                pass
        return min(nxt, self._udp_later.next_due)

    def _tick(self) -> None:
        """Frame ``frame_k`` is due: send it to every streaming client (unless lost)."""
        k = self.frame_k
        self.frame_k += 1
        if self.frames and k - self.start_frame == self.frames:
            for c in list(self.clients.values()):
                if c.divisor:
                    self._send(c, q.encode_packet(q.PACKET_NO_MORE_DATA))
                    c.divisor = 0
            return
        if self.frames and k - self.start_frame > self.frames:
            return
        streaming = [c for c in self.clients.values() if c.divisor and (k - self.start_frame) % c.divisor == 0]
        if not streaming:
            return
        if self.loss and self.rng.random() < self.loss:
            self.lost_frames += 1
            self.lost_log.append(k)
            return
        self.capture_log.append((k, self._wall0 + round((self._due(k) - self._mono0) * 1e9)))
        f = self.source.frame(k)
        cache: dict[tuple[str, ...], bytes] = {}
        for c in streaming:
            pkt = cache.get(c.comps)
            if pkt is None:
                pkt = cache[c.comps] = q.encode_data(k, self._stamp_us(k), encode_components(f, c.comps, self.rate_hz))
            if self.bad_every and k % self.bad_every == self.bad_every - 1:
                pkt = q.encode_packet(q.PACKET_DATA, q.DATA_HEADER.pack(0, k, 1000) + b"\x07" * 24)
                self.bad_sent += 1
                self.bad_log.append(k)
            self._deliver(c, pkt)
        self.send_log.append((k, time.time_ns()))
        self.sent_frames += 1

    def _restart(self) -> None:
        for c in list(self.clients.values()):
            self._send(c, q.encode_packet(q.PACKET_EVENT, bytes([q.EVENT_QTM_SHUTTING_DOWN])))
        self._close_all()
        self.restarts += 1
        if self._stop.wait(self.restart_down_s):
            return
        self.frame_k = self.start_frame
        self._epoch = time.monotonic()
        self._listen()

    def serve(self, duration_s: float = 0.0) -> None:
        """Run until ``stop()`` (or ``duration_s`` seconds). Frames follow the measurement's schedule;
        if this process was held up for over 0.5 s, the frames it missed are skipped (as lost: QTM's
        cameras do not wait either)."""
        t0 = self._epoch = time.monotonic()
        restart_at = t0 + self.restart_every_s if self.restart_every_s else float("inf")
        try:
            while not self._stop.is_set():
                now = time.monotonic()
                if duration_s and now - t0 >= duration_s:
                    break
                if now >= restart_at:
                    self._restart()
                    restart_at = time.monotonic() + self.restart_every_s
                    continue
                next_due = self._due(self.frame_k)
                wake = min(next_due, self._release())
                for key, _ev in self.sel.select(timeout=max(0.0, min(wake - now, 0.05))):
                    if key.data is None:
                        self._accept()
                    elif key.fileobj in self.clients:
                        self._read(key.data)
                for c in list(self.clients.values()):
                    if c.outbuf:
                        self._flush(c)
                now = time.monotonic()
                if now - next_due > 0.5:
                    behind = int((now - next_due) * self.rate_hz)
                    self.lost_log.extend(range(self.frame_k, self.frame_k + behind))
                    self.lost_frames += behind
                    self.frame_k += behind
                elif now >= next_due:
                    self._tick()
        finally:
            self._close_all()

    def start(self) -> "QTMSimServer":
        self._thread = threading.Thread(target=self.serve, name="qtm-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.udp.close()
