"""A NatNet server for tests, demos and replays: Motive's command and data channels on real UDP sockets.

:class:`NatNetServer` answers the command channel as Motive does (NAT_CONNECT and discovery with
NAT_SERVERINFO, NAT_REQUEST_MODELDEF with NAT_MODELDEF, the ``FrameRate`` request with a float,
keep-alives and disconnects noted) and sends frames unicast to every client that connected, to a
multicast group, and to any extra addresses. It holds packets as bytes, so the same server
replays a capture's own server info, model definitions and frames (:func:`replay`) or serves
the synthetic actor (:class:`ActorStream`, encoded by :mod:`mocapgraph.formats.natnet_encode`
for NatNet 3.0, 4.0, 4.1 or 4.2) with injected loss and restarts (:func:`simulate`).
"""
from __future__ import annotations

import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np

from ..formats import natnet as nn
from ..formats import natnet_encode as ne
from ..formats.device_file import DeviceConfig, device_or_default

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


# ----- the synthetic actor as Motive would stream it ----------------------------------------
@dataclass
class ActorStream:
    """The synthetic actor as NatNet frames: its markers as a skeleton asset's labelled markers (and
    marker set), its first ``n_bodies`` limbs as rigid bodies, ``n_unlabelled`` stray markers."""

    layout: str = "plug_in_gait"
    rate_hz: float = 120.0
    n_bodies: int = 5
    n_unlabelled: int = 2
    seed: int = 0
    dropout_rate_hz: float = 0.0
    noise_mm: float = 0.0
    device: str = ""
    up_axis: str = "y"
    dev: DeviceConfig = field(init=False)

    def __post_init__(self) -> None:
        from ..kinematics.synthetic.actor import CaptureOptions, SyntheticActor

        self.actor = SyntheticActor(self.layout, rate=self.rate_hz, seed=self.seed,
                                    options=CaptureOptions(noise_mm=self.noise_mm,
                                                           dropout_rate_hz=self.dropout_rate_hz))
        self.dev = device_or_default(self.device, self.up_axis)
        self.labels = list(self.actor.skeleton.marker_labels)
        limbs = list(self.actor.skeleton.limb_names)
        self.n_bodies = min(self.n_bodies, len(limbs))
        self.body_names = limbs[: self.n_bodies]

    def model_defs(self) -> nn.ModelDefs:
        defs = nn.ModelDefs(marker_sets={"Actor": list(self.labels), "all": [f"Actor_{m}" for m in self.labels]})
        defs.skeletons["Actor"] = (ACTOR_ID, [])
        for k, name in enumerate(self.body_names):
            defs.rigid_bodies.append(nn.RigidBodyDef(name, FIRST_BODY_ID + k, -1, np.zeros(3, np.float32)))
        return defs

    def world(self, a: int, b: int):
        """Ground truth of session frames a..b-1: (markers [T,M,3] NaN where hidden, body positions
        [T,R,3], body wxyz [T,R,4]) in the world frame."""
        n = self.actor.n_frames
        cap = self.actor.capture(a % n, min(a % n + (b - a), n))
        return cap.markers, cap.limb_centroids[:, : self.n_bodies], cap.limb_quat[:, : self.n_bodies]

    def frames(self, start: int = 0, count: int = 0, chunk: int = 120) -> Iterator[nn.Frame]:
        """NatNet frames numbered from ``start`` (device axes; 0 = endless)."""
        from scipy.spatial.transform import Rotation

        k = 0
        r_dev = Rotation.from_matrix(self.dev.rotation.T)
        while not count or k < count:
            a = start + k
            n = chunk if not count else min(chunk, count - k)
            n = min(n, self.actor.n_frames - a % self.actor.n_frames)
            markers, bpos, bquat = self.world(a, a + n)
            for i in range(markers.shape[0]):
                yield self._frame(a + i, markers[i], bpos[i], bquat[i], r_dev)
            k += markers.shape[0]

    def _frame(self, number: int, markers: np.ndarray, bpos: np.ndarray, bquat: np.ndarray, r_dev) -> nn.Frame:
        from scipy.spatial.transform import Rotation

        m = len(self.labels)
        seen = ~np.isnan(markers).any(axis=1)
        dev_m = np.where(seen[:, None], self.dev.points_from_world(np.nan_to_num(markers)), 0.0).astype(np.float32)
        lm = np.zeros(m + self.n_unlabelled, nn.LABELLED_MARKER)
        lm["id"][:m] = (ACTOR_ID << 16) | np.arange(1, m + 1)
        lm["pos"][:m] = dev_m
        lm["size"] = 0.014
        lm["params"][:m] = np.where(seen, nn.MARKER_PC_SOLVED | nn.MARKER_HAS_MODEL, nn.MARKER_OCCLUDED)
        lm["residual"] = 0.0002
        stray = np.float32(0.5) + np.arange(self.n_unlabelled * 3, dtype=np.float32).reshape(-1, 3) * 0.1
        lm["id"][m:] = 50000 + np.arange(self.n_unlabelled)
        lm["pos"][m:] = stray + np.float32(number % 100) * 0.001
        lm["params"][m:] = nn.MARKER_UNLABELLED | nn.MARKER_PC_SOLVED
        rb = np.zeros(self.n_bodies, nn.RIGID_BODY)
        rb["id"] = FIRST_BODY_ID + np.arange(self.n_bodies)
        rb["pos"] = self.dev.points_from_world(bpos)
        q = (r_dev * Rotation.from_quat(bquat, scalar_first=True)).as_quat()  # x, y, z, w
        rb["quat_xyzw"] = q
        rb["error"] = 0.0003 + 0.0001 * np.arange(self.n_bodies)
        rb["params"] = nn.RIGID_BODY_TRACKING_VALID
        t = number / self.rate_hz
        mid = int(round(t * CLOCK_HZ))
        tc = (int(t // 3600) << 24) | (int(t // 60 % 60) << 16) | (int(t % 60) << 8) | int(number % self.rate_hz)
        return nn.Frame(number, {"Actor": dev_m, "all": dev_m}, np.zeros((0, 3), np.float32), rb, {}, lm,
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
@dataclass
class Faults:
    """What the simulator breaks: a fraction of frames never sent (seeded), a restart (the server
    gone for ``restart_gap_s`` after ``restart_after`` frames, its frame numbers starting over)."""

    loss: float = 0.0
    restart_after: int = 0
    restart_gap_s: float = 2.0
    seed: int = 0
    dropped: list[int] = field(default_factory=list)


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

        def packets() -> Iterator[tuple[float, bytes]]:
            for f in frames:
                if faults.loss and rng.random() < faults.loss:
                    faults.dropped.append(f.frame_number)
                    yield f.timestamp, b""
                    continue
                yield f.timestamp, ne.frame(f, version)

        for t, packet in _timed(server, packets(), stream.rate_hz):
            sent += bool(packet)
        server.close()
        if not faults.restart_after or (count and sent + len(faults.dropped) >= count):
            return sent
        faults.restart_after, number = 0, 0  # one restart: numbering starts over
        time.sleep(faults.restart_gap_s)


def _timed(server: NatNetServer, items: Iterator[tuple[float, bytes]], rate_hz: float) -> Iterator[tuple[float, bytes]]:
    """Send packets one frame period apart (b"" = a dropped frame: its slot passes unsent)."""
    t0 = time.monotonic()
    for k, (t, packet) in enumerate(items):
        due = t0 + k / rate_hz
        while True:
            server.serve()
            wait = due - time.monotonic()
            if wait <= 0:
                break
            time.sleep(min(wait, 0.002))
        if packet:
            server.send(packet)
        yield t, packet
