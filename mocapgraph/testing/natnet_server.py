"""A NatNet server for tests, demos and replays: Motive's command and data channels on real UDP sockets.

:class:`NatNetServer` answers the command channel as Motive does (NAT_CONNECT and discovery with
NAT_SERVERINFO, NAT_REQUEST_MODELDEF with NAT_MODELDEF, the ``FrameRate`` request with a float,
keep-alives and disconnects noted) and sends frames unicast to every client that connected, to a
multicast group, and to any extra addresses. It holds packets as bytes, so the same server
replays a capture's own server info, model definitions and frames (``device replay``) or serves
a source (:class:`ActorStream`: the synthetic actor with its skeleton, or a C3D, TRC or bag's
markers; encoded by :mod:`mocapgraph.formats.natnet_encode` for NatNet 3.0, 4.0, 4.1 or 4.2)
with injected loss, restarts, delay and clock drift (:func:`simulate`). Sources and the delay and
drift injector are shared with the QTM simulator (:mod:`mocapgraph.testing.sim_sources`).
"""
from __future__ import annotations

import socket
import struct
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable, Iterator

import numpy as np

from ..formats import natnet as nn
from ..formats import natnet_encode as ne
from ..formats.device_file import DeviceConfig, device_or_default
from .sim_sources import ActorSource, DelayLine, LinkFaults, RecordedMarkers, is_recording

NAT_DISCOVERY = 14
ACTOR_ID = 1          # the skeleton id the actor's labelled markers carry as their model id
FIRST_BODY_ID = 101   # rigid bodies get ids from here
CLOCK_HZ = 10_000_000


class NatNetServer:
    """Command channel + frame sending on ``host`` (see module doc). ``command_port`` 0 = any."""

    def __init__(self, info_packet: bytes, defs_packet: bytes, host: str = "127.0.0.1", command_port: int = 1510,
                 multicast_group: str = "", data_port: int = 1511, targets: list[tuple[str, int]] | None = None,
                 rate_hz: float = 0.0) -> None:
        self.info_packet, self.defs_packet = info_packet, defs_packet
        self.host, self.rate_hz = host, rate_hz
        self.clients: dict[tuple[str, int], float] = {}
        self.targets = list(targets or [])
        self.requests: dict[int, int] = {}
        self.cmd = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.cmd.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.cmd.bind((host, command_port))
        self.cmd.setblocking(False)
        self.command_port = self.cmd.getsockname()[1]
        self.group = (multicast_group, data_port) if multicast_group else None
        if self.group:
            self.cmd.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(host))
            self.cmd.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self.sent = 0

    def serve(self) -> int:
        """Answer every waiting command packet; returns how many were handled."""
        n = 0
        while True:
            try:
                data, addr = self.cmd.recvfrom(65536)
            except (BlockingIOError, InterruptedError, ConnectionError):
                return n
            except OSError:
                return n
            n += 1
            msg = nn.message_id(data)
            self.requests[msg] = self.requests.get(msg, 0) + 1
            if msg in (nn.NAT_CONNECT, NAT_DISCOVERY):
                self._reply(self.info_packet, addr)
                if msg == nn.NAT_CONNECT:
                    self.clients[addr] = time.monotonic()
            elif msg == nn.NAT_REQUEST_MODELDEF:
                self._reply(self.defs_packet, addr)
            elif msg == nn.NAT_KEEPALIVE:
                if addr in self.clients:
                    self.clients[addr] = time.monotonic()
            elif msg == nn.NAT_DISCONNECT:
                self.clients.pop(addr, None)
            elif msg == nn.NAT_REQUEST:
                text = data[4:].split(b"\0", 1)[0]
                if text == b"FrameRate" and self.rate_hz:
                    self._reply(struct.pack("<HHf", nn.NAT_RESPONSE, 4, self.rate_hz), addr)
                else:
                    self._reply(struct.pack("<HHi", nn.NAT_RESPONSE, 4, 0), addr)

    def _reply(self, packet: bytes, addr: tuple[str, int]) -> None:
        try:
            self.cmd.sendto(packet, addr)
        except OSError:
            pass

    def send(self, packet: bytes) -> None:
        """One data packet to the multicast group (as Motive multicasting: no unicast copies), else to
        every client that connected; and to the extra targets."""
        dests = ([self.group] if self.group else list(self.clients)) + self.targets
        for addr in dests:
            self._reply(packet, addr)
        self.sent += 1

    def close(self) -> None:
        self.cmd.close()


# ----- a marker or skeleton source as Motive would stream it -----------------------------------
@dataclass
class ActorStream:
    """A source as NatNet frames. The synthetic actor (``source`` '' or 'actor'): its markers as a
    skeleton asset's labelled markers (and marker set), its limbs as that skeleton's bones (global
    poses; bone ``k`` of ``bone_dropout_every`` N > 0 untracked on frames k with k % N == 0, as
    Motive sends it: zeros, tracking-valid bit clear), its first ``n_bodies`` limbs as rigid bodies,
    ``n_unlabelled`` stray markers (``skeleton`` False: the asset without bones; ``skeleton_local``:
    bones relative to their parent, Motive's "Local" skeleton coordinates). A recording (``source`` a C3D, TRC or bag path, ``topic`` a
    bag's MarkerFrame topic): its labelled markers and residuals at its own rate, its frames
    looping; a skeleton asset without bones owns them, and there are no rigid bodies."""

    layout: str = "plug_in_gait"
    rate_hz: float = 120.0
    n_bodies: int = 5
    n_unlabelled: int = 2
    seed: int = 0
    dropout_rate_hz: float = 0.0
    noise_mm: float = 0.0
    device: str = ""
    up_axis: str = "y"
    source: str = ""
    topic: str = ""
    bone_dropout_every: int = 0
    skeleton: bool = True
    skeleton_local: bool = False
    dev: DeviceConfig = field(init=False)

    def __post_init__(self) -> None:
        self.dev = device_or_default(self.device, self.up_axis)
        self.recording: RecordedMarkers | None = None
        if is_recording(self.source):
            self.recording = RecordedMarkers(self.source, self.topic or None)
            self.rate_hz, self.labels, self.n_bodies = self.recording.rate_hz, list(self.recording.labels), 0
            self.body_names, self.bone_names = [], []
            self.bone_parent = np.zeros(0, np.int64)
            self.n_frames = self.recording.n_frames
            return
        self.actor_source = ActorSource(self.layout, self.rate_hz, self.seed, self.noise_mm, self.dropout_rate_hz)
        self.actor = self.actor_source.actor
        self.n_frames = self.actor.n_frames
        self.labels = list(self.actor_source.labels)
        limbs = list(self.actor_source.limb_names)
        self.n_bodies = min(self.n_bodies, len(limbs))
        self.body_names = limbs[: self.n_bodies]
        self.bone_names = limbs if self.skeleton else []
        self.bone_parent = self.actor_source.limb_parent if self.skeleton else np.zeros(0, np.int64)

    def bone_offsets(self) -> np.ndarray:
        """Each bone's origin less its parent's (its own for a root) in the session's first frame, world m."""
        o = self.bones(0, 1)[0][0]
        par = self.bone_parent
        return np.where((par >= 0)[:, None], o - o[np.maximum(par, 0)], o)

    def model_defs(self) -> nn.ModelDefs:
        defs = nn.ModelDefs(marker_sets={"Actor": list(self.labels), "all": [f"Actor_{m}" for m in self.labels]})
        off = self.dev.points_from_world(self.bone_offsets()) - self.dev.points_from_world(np.zeros(3)) \
            if self.bone_names else np.zeros((0, 3))
        bones = [nn.RigidBodyDef(name, k + 1, int(self.bone_parent[k]) + 1, off[k].astype(np.float32))
                 for k, name in enumerate(self.bone_names)]
        defs.skeletons["Actor"] = (ACTOR_ID, bones)
        for k, name in enumerate(self.body_names):
            defs.rigid_bodies.append(nn.RigidBodyDef(name, FIRST_BODY_ID + k, -1, np.zeros(3, np.float32)))
        return defs

    def world(self, a: int, b: int):
        """Ground truth of session frames a..b-1: (markers [T,M,3] NaN where hidden, body positions
        [T,R,3], body wxyz [T,R,4]) in the world frame."""
        if self.recording is not None:
            m = self.recording.markers(a, b)[0]
            return m, np.zeros((len(m), 0, 3)), np.zeros((len(m), 0, 4))
        cap = self.actor_source.window(a, b)
        return cap.markers, cap.limb_centroids[:, : self.n_bodies], cap.limb_quat[:, : self.n_bodies]

    def bones(self, a: int, b: int):
        """Ground truth of the skeleton's bones in frames a..b-1: (origins [T,L,3] m world, wxyz
        [T,L,4] world, tracked bool [T,L]); empty for a recording."""
        if self.recording is not None or not self.bone_names:
            t = min(b - a, self.n_frames - a % self.n_frames)
            return np.zeros((t, 0, 3)), np.zeros((t, 0, 4)), np.zeros((t, 0), bool)
        src = self.actor_source
        cap = src.window(a, b)
        pos = src.segment_origins(cap.joint_centres, cap.limb_centroids)
        t, n = pos.shape[:2]
        ok = np.ones((t, n), bool)
        if self.bone_dropout_every:
            k = np.arange(a, a + t)
            hit = k % self.bone_dropout_every == 0
            ok[np.flatnonzero(hit), (k % n)[hit]] = False
        return pos, cap.limb_quat, ok

    def frames(self, start: int = 0, count: int = 0, chunk: int = 120) -> Iterator[nn.Frame]:
        """NatNet frames numbered from ``start`` (device axes; 0 = endless)."""
        from scipy.spatial.transform import Rotation

        k = 0
        r_dev = Rotation.from_matrix(self.dev.rotation.T)
        while not count or k < count:
            a = start + k
            n = chunk if not count else min(chunk, count - k)
            n = min(n, self.n_frames - a % self.n_frames)
            markers, bpos, bquat = self.world(a, a + n)
            res = self.recording.markers(a, a + n)[1] if self.recording is not None else \
                np.full(markers.shape[:2], 0.0002)
            spos, squat, sok = self.bones(a, a + n)
            if self.skeleton_local:
                spos, squat = self._local(spos, squat)
            for i in range(markers.shape[0]):
                yield self._frame(a + i, markers[i], res[i], (bpos[i], bquat[i]), (spos[i], squat[i], sok[i]), r_dev)
            k += markers.shape[0]

    def _local(self, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bone poses [T, L] relative to the parent bone (roots unchanged)."""
        from ..kinematics.quaternion import quat_conjugate, quat_multiply, quat_rotate

        par = np.maximum(self.bone_parent, 0)
        child = (self.bone_parent >= 0)[None, :, None]
        inv = quat_conjugate(quat[:, par])
        return (np.where(child, quat_rotate(inv, pos - pos[:, par]), pos),
                np.where(child, quat_multiply(inv, quat), quat))

    def _poses(self, ids: np.ndarray, pos: np.ndarray, quat_wxyz: np.ndarray, ok: np.ndarray, r_dev,
               in_device: np.ndarray | None = None) -> np.ndarray:
        """RIGID_BODY rows in device axes (``in_device`` False: rows kept as they are, parent-relative
        bones; untracked: zeros, tracking-valid bit clear, as Motive sends)."""
        from scipy.spatial.transform import Rotation

        rb = np.zeros(len(ids), nn.RIGID_BODY)
        rb["id"] = ids
        if len(ids):
            keep = np.zeros(len(ids), bool) if in_device is None else ~in_device
            p = np.where(keep[:, None], pos, self.dev.points_from_world(pos))
            rb["pos"] = np.where(ok[:, None], p, 0.0)
            q = (r_dev * Rotation.from_quat(quat_wxyz, scalar_first=True)).as_quat()  # x, y, z, w
            q = np.where(keep[:, None], np.asarray(quat_wxyz)[:, [1, 2, 3, 0]], q)
            rb["quat_xyzw"] = np.where(ok[:, None], q, 0.0)
        rb["params"] = np.where(ok, nn.RIGID_BODY_TRACKING_VALID, 0)
        return rb

    def _frame(self, number: int, markers: np.ndarray, residual: np.ndarray, body, bone, r_dev) -> nn.Frame:
        m = len(self.labels)
        seen = ~np.isnan(markers).any(axis=1)
        dev_m = np.where(seen[:, None], self.dev.points_from_world(np.nan_to_num(markers)), 0.0).astype(np.float32)
        lm = np.zeros(m + self.n_unlabelled, nn.LABELLED_MARKER)
        lm["id"][:m] = (ACTOR_ID << 16) | np.arange(1, m + 1)
        lm["pos"][:m] = dev_m
        lm["size"] = 0.014
        lm["params"][:m] = np.where(seen, nn.MARKER_PC_SOLVED | nn.MARKER_HAS_MODEL, nn.MARKER_OCCLUDED)
        lm["residual"][:m] = np.where(seen, residual, 0.0)
        lm["residual"][m:] = 0.0002
        stray = np.float32(0.5) + np.arange(self.n_unlabelled * 3, dtype=np.float32).reshape(-1, 3) * 0.1
        lm["id"][m:] = 50000 + np.arange(self.n_unlabelled)
        lm["pos"][m:] = stray + np.float32(number % 100) * 0.001
        lm["params"][m:] = nn.MARKER_UNLABELLED | nn.MARKER_PC_SOLVED
        rb = self._poses(FIRST_BODY_ID + np.arange(self.n_bodies), *body, np.ones(self.n_bodies, bool), r_dev)
        rb["error"] = 0.0003 + 0.0001 * np.arange(self.n_bodies)
        skeletons = {}
        if self.bone_names:
            skeletons[ACTOR_ID] = self._poses((ACTOR_ID << 16) | np.arange(1, len(self.bone_names) + 1), *bone, r_dev,
                                              (self.bone_parent < 0) if self.skeleton_local else None)
        t = number / self.rate_hz
        mid = int(round(t * CLOCK_HZ))
        tc = (int(t // 3600) << 24) | (int(t // 60 % 60) << 16) | (int(t % 60) << 8) | int(number % self.rate_hz)
        return nn.Frame(number, {"Actor": dev_m, "all": dev_m}, np.zeros((0, 3), np.float32), rb, skeletons, lm,
                        tc, 0, t, mid, mid + CLOCK_HZ // 500, mid + 3 * CLOCK_HZ // 1000,
                        int(t), int((t % 1) * 2**32) & 0xFFFFFFFF, 0, 0)

    def server_info(self, version: nn.Version, multicast_group: str = "", data_port: int = 1511) -> nn.ServerInfo:
        app = {(3, 0): (2, 3, 0, 0), (4, 0): (3, 0, 0, 0), (4, 1): (3, 1, 0, 0)}.get(version, (3, 2, 0, 0))
        return nn.ServerInfo("Motive", app, (*version, 0, 0), CLOCK_HZ, data_port, bool(multicast_group),
                             multicast_group or "0.0.0.0")


def paced_send(server: NatNetServer, items: Iterator[tuple[float, bytes]], speed: float = 1.0,
               until: Callable[[], bool] | None = None) -> int:
    """Send (time s, packet) pairs at their times / ``speed`` (0 = as fast as possible), answering the
    command channel meanwhile; returns packets sent."""
    t0 = time.monotonic()
    n = 0
    first: float | None = None
    for t, packet in items:
        first = t if first is None else first
        due = t0 + (t - first) / speed if speed > 0 else 0.0
        while True:
            server.serve()
            wait = due - time.monotonic()
            if wait <= 0:
                break
            time.sleep(min(wait, 0.002))
        if until is not None and until():
            break
        server.send(packet)
        n += 1
    server.serve()
    return n


def wait_for_client(server: NatNetServer, timeout_s: float) -> bool:
    """Serve the command channel until a client connected (True) or ``timeout_s`` passed."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        server.serve()
        if server.clients:
            return True
        time.sleep(0.005)
    return False


# ----- replaying a capture ------------------------------------------------------------------
def capture_packets(path) -> tuple[bytes, bytes, list[tuple[float, bytes]]]:
    """A pcapng capture of a NatNet session -> (its server info packet, its model definitions
    packet, [(capture time s, frame packet)...]). ValueError when it holds no NatNet session."""
    from .pcapng import read_udp

    info = defs = b""
    frames: list[tuple[float, bytes]] = []
    for d in read_udp(path):
        if d.src[1] not in (1510, 1511):  # the server's ports: what it sent
            continue
        msg = nn.message_id(d.payload)
        if msg == nn.NAT_SERVERINFO and not info:
            info = d.payload
        elif msg == nn.NAT_MODELDEF and not defs:
            defs = d.payload
        elif msg == nn.NAT_FRAMEOFDATA:
            frames.append((d.time_ns / 1e9, d.payload))
    if not info or not frames:
        raise ValueError(f"{path}: no NatNet server info or no frames of data from ports 1510/1511")
    return info, defs or ne.model_defs(nn.ModelDefs(), nn.decode_server_info(info).version), frames


def wait_until_ready(server: NatNetServer, timeout_s: float) -> bool:
    """Serve the command channel until a client connected and asked for the model definitions
    (True), or ``timeout_s`` passed (False)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        server.serve()
        if server.clients and server.requests.get(nn.NAT_REQUEST_MODELDEF):
            t = time.monotonic() + 0.05  # the definitions' reply is on its way: let it land first
            while time.monotonic() < t:
                server.serve()
                time.sleep(0.002)
            return True
        time.sleep(0.002)
    return False


# ----- the simulator ------------------------------------------------------------------------
#: mid-exposure to transmit in the simulator's frames (ActorStream._frame): 3 ms
SYSTEM_LATENCY_NS = 3_000_000


@dataclass
class Faults:
    """What the simulator breaks: a fraction of frames never sent (seeded), a restart (the server
    gone for ``restart_gap_s`` after ``restart_after`` frames, its frame numbers starting over),
    each frame held back a random ``delay_ms`` (lo, hi) on its way (datagrams may overtake each
    other) and the server's clock running ``drift_ppm`` fast (the injector the QTM simulator uses,
    :class:`~mocapgraph.testing.sim_sources.LinkFaults`). ``captured`` logs (frame number, its true
    mid-exposure time on this machine's wall clock, ns) of every frame sent: what a reader's
    capture stamps should equal."""

    loss: float = 0.0
    restart_after: int = 0
    restart_gap_s: float = 2.0
    seed: int = 0
    dropped: list[int] = field(default_factory=list)
    delay_ms: tuple[float, float] = (0.0, 0.0)
    drift_ppm: float = 0.0
    captured: deque = field(default_factory=lambda: deque(maxlen=100_000))
    #: how late the simulator itself sent frames (after their slot and injected delay), ms: the
    #: worst, and how many over 0.5 s (a busy machine stalling this thread; a reader sees a stall)
    late_ms_max: float = 0.0
    late_over_500ms: int = 0

    def __post_init__(self) -> None:
        self.link = LinkFaults(self.delay_ms, self.drift_ppm, self.seed)

    def sent_late(self, due: float, now: float) -> None:
        """Note a frame sent at ``now`` that was due at ``due`` (monotonic s)."""
        late = (now - due) * 1000.0
        self.late_ms_max = max(self.late_ms_max, late)
        self.late_over_500ms += late > 500.0

    def on_device_clock(self, f: nn.Frame) -> nn.Frame:
        """``f`` with its clock fields read off a server clock running ``drift_ppm`` fast."""
        if not self.drift_ppm:
            return f
        d = self.link.device_s
        return replace(f, timestamp=d(f.timestamp), mid_exposure_ticks=round(d(f.mid_exposure_ticks)),
                       data_received_ticks=round(d(f.data_received_ticks)), transmit_ticks=round(d(f.transmit_ticks)))


def simulate(stream: ActorStream, version: nn.Version, host: str = "127.0.0.1", command_port: int = 1510,
             multicast_group: str = "", data_port: int = 1511, count: int = 0, faults: Faults | None = None,
             start_frame: int = 0, on_ready: Callable[[NatNetServer], None] | None = None,
             wait_s: float = 0.0) -> int:
    """Serve ``stream`` as a Motive NatNet server in real time; returns frames sent (dropped ones not
    counted; their numbers go to ``faults.dropped``). ``wait_s`` > 0: wait that long for a client
    to connect and ask for the model definitions before streaming."""
    faults = faults or Faults()
    rng = np.random.default_rng(faults.seed)
    info = ne.server_info(stream.server_info(version, multicast_group, data_port))
    defs = ne.model_defs(stream.model_defs(), version)
    sent = 0
    number = start_frame
    while True:
        server = NatNetServer(info, defs, host, command_port, multicast_group, data_port, rate_hz=stream.rate_hz)
        command_port = server.command_port
        if on_ready is not None:
            on_ready(server)
        if wait_s:
            wait_until_ready(server, wait_s)
        todo = count - sent - len(faults.dropped) if count else 0   # frames to go, sent or dropped
        if faults.restart_after:
            todo = min(todo, faults.restart_after) if todo else faults.restart_after
        frames = stream.frames(number, todo)

        def packets() -> Iterator[tuple[int, bytes]]:
            for f in frames:
                if faults.loss and rng.random() < faults.loss:
                    faults.dropped.append(f.frame_number)
                    yield f.frame_number, b""
                    continue
                yield f.frame_number, ne.frame(faults.on_device_clock(f), version)

        for packet in _timed(server, packets(), stream.rate_hz, faults):
            sent += bool(packet)
        server.close()
        if not faults.restart_after or (count and sent + len(faults.dropped) >= count):
            return sent
        faults.restart_after, number = 0, 0  # one restart: numbering starts over
        time.sleep(faults.restart_gap_s)


def _pass_time(server: NatNetServer, held: DelayLine, until: float, faults: Faults) -> None:
    """Answer the command channel and send held-back packets as they fall due, until ``until``."""
    while True:
        server.serve()
        now = time.monotonic()
        for due, packet in held.pop_due(now):
            server.send(packet)
            faults.sent_late(due, now)
        if now >= until:
            return
        time.sleep(max(0.0, min(until - now, held.next_due - now, 0.002)))


def _timed(server: NatNetServer, items: Iterator[tuple[int, bytes]], rate_hz: float,
           faults: Faults) -> Iterator[bytes]:
    """Send (frame number, packet) one frame period apart (b"" = a dropped frame: its slot passes
    unsent), each after its injected delay; a frame's slot is its transmit time, so its true
    mid-exposure is the system latency before (logged in ``faults.captured``)."""
    t0, wall0 = time.monotonic(), time.time_ns()
    held = DelayLine()
    for k, (number, packet) in enumerate(items):
        due = t0 + k / rate_hz
        _pass_time(server, held, due, faults)
        if packet:
            faults.captured.append((number, wall0 + round((due - t0) * 1e9) - SYSTEM_LATENCY_NS))
            if faults.link.delays:
                hold = due + faults.link.hold_s()
                held.push(hold, (hold, packet))
            else:
                server.send(packet)
                faults.sent_late(due, time.monotonic())
        yield packet
    while len(held):
        _pass_time(server, held, held.next_due, faults)
