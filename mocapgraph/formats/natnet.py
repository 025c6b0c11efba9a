"""Decodes OptiTrack NatNet packets (server info, model definitions, frames of data), NatNet 3.0 to 4.2.

Pure: bytes in, numpy arrays and dataclasses out; no sockets, no bus. Layout as OptiTrack's public
protocol description (PacketClient / NatNetClient.py) gives it: every packet starts with a
little-endian uint16 message id and uint16 byte count. Units are NatNet's own (metres, Motive's
axes: Y up), quaternions are kept as NatNet sends them (x, y, z, w); a reader converts.

Version-dependent fields handled:

- 3.0: rigid bodies carry no marker lists in frames; labelled markers have a residual; frames end
  with three uint64 high-resolution timestamps (camera mid-exposure, data received, transmit).
- 4.0: rigid body descriptions carry marker names.
- 4.1 and later: every frame section (marker sets, other markers, rigid bodies, skeletons, assets,
  labelled markers, force plates, devices) has a byte count after its item count, an assets section
  follows the skeletons, two uint32 precision (PTP) timestamps precede the frame params, and every
  model description has a byte count after its type (unknown types are skipped by it; before 4.1
  an unknown type is an error: nothing says how long it is).

Hostile input: every count is checked against the bytes left before anything is allocated, and a
malformed packet raises ONE :class:`NatNetError` naming the packet, the field and the fault.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from .errors import FormatError

NAT_CONNECT, NAT_SERVERINFO, NAT_REQUEST, NAT_RESPONSE = 0, 1, 2, 3
NAT_REQUEST_MODELDEF, NAT_MODELDEF, NAT_REQUEST_FRAMEOFDATA, NAT_FRAMEOFDATA = 4, 5, 6, 7
NAT_MESSAGESTRING, NAT_DISCONNECT, NAT_KEEPALIVE = 8, 9, 10
NAT_UNRECOGNIZED_REQUEST = 100
MESSAGE_NAMES = {0: "connect", 1: "server info", 2: "request", 3: "response", 4: "model definition request",
                 5: "model definitions", 6: "frame request", 7: "frame of data", 8: "message string",
                 9: "disconnect", 10: "keep-alive", 12: "echo request", 13: "echo response",
                 14: "discovery", 100: "unrecognized request"}

DESC_MARKERSET, DESC_RIGIDBODY, DESC_SKELETON, DESC_FORCEPLATE, DESC_DEVICE, DESC_CAMERA = 0, 1, 2, 3, 4, 5

Version = tuple[int, int]

#: a rigid body in a frame, NatNet 3.0+: id, position (m), orientation (x, y, z, w), mean marker error (m), params
RIGID_BODY = np.dtype([("id", "<i4"), ("pos", "<f4", 3), ("quat_xyzw", "<f4", 4), ("error", "<f4"),
                       ("params", "<i2")])
#: a labelled marker, NatNet 3.0+: id (model id << 16 | marker id), position (m), size (m), params, residual (m)
LABELLED_MARKER = np.dtype([("id", "<i4"), ("pos", "<f4", 3), ("size", "<f4"), ("params", "<i2"),
                            ("residual", "<f4")])
POINT = np.dtype(("<f4", 3))

# labelled marker params bits
MARKER_OCCLUDED, MARKER_PC_SOLVED, MARKER_MODEL_SOLVED = 0x01, 0x02, 0x04
MARKER_HAS_MODEL, MARKER_UNLABELLED, MARKER_ACTIVE = 0x08, 0x10, 0x20
RIGID_BODY_TRACKING_VALID = 0x01
FRAME_RECORDING, FRAME_MODELS_CHANGED = 0x01, 0x02


class NatNetError(FormatError):
    """A NatNet packet that cannot be decoded; ``str()`` is one line: what, where, why."""

    def __init__(self, fault: str) -> None:
        super().__init__("natnet", fault)


class _Buf:
    """A bounded little-endian cursor over one packet: every read checks the bytes left."""

    def __init__(self, data: bytes, start: int, end: int, what: str) -> None:
        self.data, self.pos, self.end, self.what = data, start, end, what

    @property
    def left(self) -> int:
        return self.end - self.pos

    def fail(self, fault: str) -> NatNetError:
        return NatNetError(f"{self.what}: {fault} (at byte {self.pos})")

    def need(self, n: int, field_name: str) -> None:
        if n > self.left:
            raise self.fail(f"truncated in {field_name}: needs {n} bytes, {self.left} left")

    def unpack(self, fmt: str, field_name: str) -> tuple:
        size = struct.calcsize("<" + fmt)
        self.need(size, field_name)
        out = struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def i32(self, field_name: str) -> int:
        return self.unpack("i", field_name)[0]

    def count(self, field_name: str, item_bytes: int) -> int:
        """An int32 item count, refused when negative or when its items cannot fit in the bytes left."""
        n = self.i32(field_name)
        if n < 0 or n * item_bytes > self.left:
            raise self.fail(f"{field_name} {n} does not fit in the {self.left} bytes left")
        return n

    def array(self, dtype: np.dtype, n: int, field_name: str) -> np.ndarray:
        self.need(n * dtype.itemsize, field_name)
        out = np.frombuffer(self.data, dtype, n, self.pos)
        self.pos += n * dtype.itemsize
        return out

    def string(self, field_name: str) -> str:
        """A NUL-terminated string (UTF-8, undecodable bytes replaced)."""
        stop = self.data.find(b"\0", self.pos, self.end)
        if stop < 0:
            raise self.fail(f"{field_name}: string without its terminating NUL")
        s = self.data[self.pos:stop].decode("utf-8", "replace")
        self.pos = stop + 1
        return s

    def skip(self, n: int, field_name: str) -> None:
        if n < 0:
            raise self.fail(f"{field_name}: negative byte count {n}")
        self.need(n, field_name)
        self.pos += n


def _has_sizes(version: Version) -> bool:
    """NatNet 4.1 and later: sections and descriptions carry their byte counts."""
    return version >= (4, 1)


def _check_version(version: Version) -> None:
    if version < (3, 0):
        raise NatNetError(f"NatNet {version[0]}.{version[1]} is not supported (3.0 and later are)")


def _open(data: bytes, expect: int | None = None) -> tuple[int, _Buf]:
    """Header -> (message id, cursor over its payload). Refuses a short packet or a bad byte count."""
    if len(data) < 4:
        raise NatNetError(f"packet of {len(data)} bytes is shorter than the 4-byte header")
    msg_id, nbytes = struct.unpack_from("<HH", data, 0)
    what = MESSAGE_NAMES.get(msg_id, f"message {msg_id}")
    if expect is not None and msg_id != expect:
        raise NatNetError(f"expected a {MESSAGE_NAMES[expect]} packet, got {what}")
    if nbytes > len(data) - 4:
        raise NatNetError(f"{what}: header says {nbytes} payload bytes, the packet has {len(data) - 4}")
    return msg_id, _Buf(data, 4, 4 + nbytes, what)


def message_id(data: bytes) -> int:
    """The message id of a packet (-1 when it is too short to have one)."""
    return struct.unpack_from("<H", data, 0)[0] if len(data) >= 2 else -1


# ----- server info ------------------------------------------------------------------------------
@dataclass(frozen=True)
class ServerInfo:
    """NAT_SERVERINFO: who is streaming and how (the clock fields exist from NatNet 3.0)."""

    app_name: str
    app_version: tuple[int, int, int, int]
    natnet_version: tuple[int, int, int, int]
    clock_hz: int = 0          # high-resolution clock ticks per second (frame timestamps), 0 = not sent
    data_port: int = 0         # UDP port frames come from, 0 = not sent
    multicast: bool = False
    multicast_group: str = ""

    @property
    def version(self) -> Version:
        return self.natnet_version[0], self.natnet_version[1]


def decode_server_info(data: bytes) -> ServerInfo:
    """A NAT_SERVERINFO packet -> ServerInfo."""
    _, b = _open(data, NAT_SERVERINFO)
    b.need(264, "application name and versions")
    raw = b.data[b.pos:b.pos + 256]
    name = raw.split(b"\0", 1)[0].decode("utf-8", "replace")  # the rest of the 256 bytes is junk
    b.pos += 256
    app = b.unpack("4B", "application version")
    nat = b.unpack("4B", "NatNet version")
    if b.left < 15:
        return ServerInfo(name, app, nat)
    clock, port, mcast = b.unpack("QHB", "connection info")
    group = ".".join(str(x) for x in b.unpack("4B", "multicast group"))
    return ServerInfo(name, app, nat, int(clock), int(port), bool(mcast), group)


# ----- model definitions ------------------------------------------------------------------------
@dataclass
class RigidBodyDef:
    """A rigid body description: offset from its parent (m), its markers' local positions (m)."""

    name: str
    id: int
    parent_id: int
    offset: np.ndarray
    marker_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    marker_labels: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    marker_names: list[str] = field(default_factory=list)


@dataclass
class ModelDefs:
    """NAT_MODELDEF: marker sets (name -> marker names), rigid bodies, skeletons; skipped descriptions."""

    marker_sets: dict[str, list[str]] = field(default_factory=dict)
    rigid_bodies: list[RigidBodyDef] = field(default_factory=list)
    skeletons: dict[str, tuple[int, list[RigidBodyDef]]] = field(default_factory=dict)
    skipped: dict[int, int] = field(default_factory=dict)  # description type -> how many

    def rigid_body_names(self) -> dict[int, str]:
        return {rb.id: rb.name for rb in self.rigid_bodies}


def _strings(b: _Buf, n: int, what: str) -> list[str]:
    return [b.string(what) for _ in range(n)]


def _rigid_body_def(b: _Buf, version: Version) -> RigidBodyDef:
    name = b.string("rigid body name")
    rid, parent = b.unpack("ii", "rigid body id")
    offset = np.array(b.unpack("3f", "rigid body offset"), np.float32)
    n = b.count("rigid body marker count", 16)
    pos = b.array(POINT, n, "rigid body marker positions").copy()
    labels = b.array(np.dtype("<i4"), n, "rigid body marker labels").copy()
    names = _strings(b, n, "rigid body marker name") if version >= (4, 0) else []
    return RigidBodyDef(name, rid, parent, offset, pos, labels, names)


def _skip_force_plate(b: _Buf) -> None:
    b.i32("force plate id")
    b.string("force plate serial")
    b.skip(4 * (2 + 3 + 144 + 12 + 2), "force plate geometry and calibration")
    _strings(b, b.count("force plate channel count", 1), "force plate channel name")


def _skip_device(b: _Buf) -> None:
    b.i32("device id")
    b.string("device name")
    b.string("device serial")
    b.skip(8, "device type")
    _strings(b, b.count("device channel count", 1), "device channel name")


def _skip_camera(b: _Buf) -> None:
    b.string("camera name")
    b.skip(28, "camera pose")


def _description(b: _Buf, kind: int, version: Version, defs: ModelDefs) -> None:
    if kind == DESC_MARKERSET:
        name = b.string("marker set name")
        defs.marker_sets[name] = _strings(b, b.count("marker set marker count", 1), "marker name")
    elif kind == DESC_RIGIDBODY:
        defs.rigid_bodies.append(_rigid_body_def(b, version))
    elif kind == DESC_SKELETON:
        name = b.string("skeleton name")
        sid = b.i32("skeleton id")
        n = b.count("skeleton rigid body count", 25)
        defs.skeletons[name] = (sid, [_rigid_body_def(b, version) for _ in range(n)])
    elif kind in (DESC_FORCEPLATE, DESC_DEVICE, DESC_CAMERA):
        {DESC_FORCEPLATE: _skip_force_plate, DESC_DEVICE: _skip_device, DESC_CAMERA: _skip_camera}[kind](b)
        defs.skipped[kind] = defs.skipped.get(kind, 0) + 1
    else:
        raise b.fail(f"unknown description type {kind} (NatNet {version[0]}.{version[1]} gives no size to skip it)")


def decode_model_defs(data: bytes, version: Version) -> ModelDefs:
    """A NAT_MODELDEF packet -> ModelDefs (force plates, devices, cameras are skipped and counted)."""
    _check_version(version)
    _, b = _open(data, NAT_MODELDEF)
    defs = ModelDefs()
    for _ in range(b.count("description count", 8)):
        kind = b.i32("description type")
        if not _has_sizes(version):
            _description(b, kind, version, defs)
            continue
        size = b.count("description byte count", 1)
        end = b.pos + size
        if kind in (DESC_MARKERSET, DESC_RIGIDBODY, DESC_SKELETON):
            sub = _Buf(b.data, b.pos, end, b.what)
            _description(sub, kind, version, defs)
        else:  # the byte count lets us pass over what we do not use, known or not
            defs.skipped[kind] = defs.skipped.get(kind, 0) + 1
        b.pos = end
    return defs


# ----- frames of data ---------------------------------------------------------------------------
@dataclass
class Frame:
    """NAT_FRAMEOFDATA. Positions m (Motive axes), quaternions x, y, z, w; clock fields in ticks of
    the server's high-resolution clock (ServerInfo.clock_hz); ``timestamp`` s since Motive started."""

    frame_number: int
    marker_sets: dict[str, np.ndarray]       # name -> float32[N, 3]
    other_markers: np.ndarray                # float32[N, 3], unlabelled ("other") markers
    rigid_bodies: np.ndarray                 # RIGID_BODY[R]
    skeletons: dict[int, np.ndarray]         # skeleton id -> RIGID_BODY[B]
    labelled_markers: np.ndarray             # LABELLED_MARKER[L]
    timecode: int
    timecode_sub: int
    timestamp: float
    mid_exposure_ticks: int
    data_received_ticks: int
    transmit_ticks: int
    precision_s: int = 0
    precision_frac: int = 0
    params: int = 0
    skipped_items: int = 0                   # assets, force plates, devices passed over

    @property
    def rigid_body_valid(self) -> np.ndarray:
        return (self.rigid_bodies["params"] & RIGID_BODY_TRACKING_VALID) != 0

    @property
    def models_changed(self) -> bool:
        return bool(self.params & FRAME_MODELS_CHANGED)

    def timecode_text(self) -> str:
        """SMPTE-style hh:mm:ss:ff.sub, as OptiTrack's clients print it."""
        tc = self.timecode
        return f"{(tc >> 24) & 255:02d}:{(tc >> 16) & 255:02d}:{(tc >> 8) & 255:02d}:{tc & 255:02d}.{self.timecode_sub}"


class _Section:
    """One frame section: its count, and from 4.1 its byte count, so it can be checked or skipped."""

    def __init__(self, b: _Buf, name: str, min_item: int, sized: bool) -> None:
        self.n = b.count(f"{name} count", min_item)
        self.end: int | None = None
        if sized:
            size = b.count(f"{name} byte count", 1)
            self.end = b.pos + size
        self.start, self.b, self.name = b.pos, b, name

    def close(self) -> None:
        if self.end is not None and self.b.pos != self.end:
            raise self.b.fail(f"{self.name} section: decoded {self.b.pos - self.start} bytes, its byte count "
                              f"says {self.end - self.start}")


def _rigid_bodies(b: _Buf, n: int, what: str) -> np.ndarray:
    return b.array(RIGID_BODY, n, what)


def _skip_analog(b: _Buf, n: int, what: str) -> None:
    """Force plates and devices before 4.1 (no byte count): id, channels of frames of float32."""
    for _ in range(n):
        b.i32(f"{what} id")
        for _ in range(b.count(f"{what} channel count", 4)):
            b.skip(4 * b.count(f"{what} channel frame count", 4), f"{what} channel data")


def decode_frame(data: bytes, version: Version) -> Frame:
    """A NAT_FRAMEOFDATA packet -> Frame (arrays are read-only views of ``data``)."""
    _check_version(version)
    _, b = _open(data, NAT_FRAMEOFDATA)
    sized = _has_sizes(version)
    number = b.i32("frame number")
    sets: dict[str, np.ndarray] = {}
    sec = _Section(b, "marker set", 5, sized)
    for _ in range(sec.n):
        name = b.string("marker set name")
        sets[name] = b.array(POINT, b.count("marker set marker count", 12), "marker set positions")
    sec.close()
    sec = _Section(b, "other marker", 12, sized)
    other = b.array(POINT, sec.n, "other marker positions")
    sec.close()
    sec = _Section(b, "rigid body", RIGID_BODY.itemsize, sized)
    bodies = _rigid_bodies(b, sec.n, "rigid bodies")
    sec.close()
    skeletons: dict[int, np.ndarray] = {}
    sec = _Section(b, "skeleton", 8, sized)
    for _ in range(sec.n):
        sid = b.i32("skeleton id")
        skeletons[sid] = _rigid_bodies(b, b.count("skeleton rigid body count", RIGID_BODY.itemsize),
                                       "skeleton rigid bodies")
    sec.close()
    skipped = 0
    if sized:  # assets (4.1+): passed over by their byte count
        sec = _Section(b, "asset", 1, True)
        b.pos, skipped = sec.end, skipped + sec.n
    sec = _Section(b, "labelled marker", LABELLED_MARKER.itemsize, sized)
    labelled = b.array(LABELLED_MARKER, sec.n, "labelled markers")
    sec.close()
    for what in ("force plate", "device"):
        sec = _Section(b, what, 8, sized)
        if sized:
            b.pos = sec.end
        else:
            _skip_analog(b, sec.n, what)
        skipped += sec.n
    tc, tc_sub, ts, mid, recv, tx = b.unpack("IIdQQQ", "timecode and timestamps")
    p_s = p_f = 0
    if sized:
        p_s, p_f = b.unpack("II", "precision timestamp")
    params = b.unpack("h", "frame params")[0]
    return Frame(number, sets, other, bodies, skeletons, labelled, tc, tc_sub, ts, mid, recv, tx,
                 p_s, p_f, params, skipped)


def split_marker_id(ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Labelled marker ids -> (model id, marker id): model in the high 16 bits, marker in the low."""
    ids = np.asarray(ids, np.int64) & 0xFFFFFFFF
    return ids >> 16, ids & 0xFFFF


# ----- commands ---------------------------------------------------------------------------------
def command(msg_id: int, payload: bytes = b"") -> bytes:
    """A client command packet: header + payload."""
    if len(payload) > 0xFFFF:
        raise NatNetError(f"command payload of {len(payload)} bytes is over 65535")
    return struct.pack("<HH", msg_id, len(payload)) + payload


def connect_command(client_name: str = "mocapgraph", natnet_version: tuple[int, int, int, int] = (3, 0, 0, 0)) -> bytes:
    """NAT_CONNECT as NatNet clients send it: a 256-byte client name, the client's version, the NatNet
    version it speaks (the captured Motive session shows 3.0.0.0 for both)."""
    name = client_name.encode()[:255].ljust(256, b"\0")
    return command(NAT_CONNECT, name + bytes(natnet_version) + bytes(natnet_version))
