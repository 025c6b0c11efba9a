"""Decodes and encodes the Qualisys QTM real-time (RT) protocol: packets, data frames, parameter XML.

Pure: bytes in, numpy arrays and dataclasses out (and back, for the simulator); no sockets, no bus.
Layout as Qualisys documents it (the RT protocol documentation; its own Python client ``qtm-rt``
reads the same bytes, and the tests hold us to it), little-endian as on QTM's base port + 1:

- every packet: uint32 size (header included), uint32 type (0 error, 1 command, 2 XML, 3 data,
  4 no more data, 6 event, ...); error, command and XML packets carry a NUL-terminated string;
- a data packet: int64 time stamp (microseconds), uint32 frame number, uint32 component count,
  then components, each with a uint32 size (its 8-byte header included) and a uint32 type, so a
  component we do not read is skipped by its size;
- 3D (labelled, in the order of the parameter XML's labels; NaN where not seen), 3D without
  labels (x, y, z, id), 6D (position + 3x3 rotation matrix, column-major), 6D Euler (position +
  three angles, degrees), the residual variants of each, skeletons (per segment: id, position,
  quaternion x y z w) and timecode (type, high and low 32 bits). Positions are millimetres in
  QTM's axes (``The_3D/AxisUpwards`` says which is up).

Hostile input: a packet header whose size is below 8 or above ``max_packet`` bytes breaks the
stream (:class:`PacketSplitter` raises; the caller reconnects); inside a data packet every count
is checked against the bytes its component holds before anything is allocated, and a malformed
packet raises ONE :class:`QTMError` naming the component and the fault. XML with a DOCTYPE
(entity tricks) or over ``MAX_XML_BYTES`` is refused.
"""
from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

from .errors import FormatError

PACKET_ERROR, PACKET_COMMAND, PACKET_XML, PACKET_DATA, PACKET_NO_MORE_DATA = 0, 1, 2, 3, 4
PACKET_C3D, PACKET_EVENT, PACKET_DISCOVER, PACKET_QTM_FILE = 5, 6, 7, 8
PACKET_NAMES = {0: "error", 1: "command", 2: "XML", 3: "data", 4: "no more data", 5: "C3D file",
                6: "event", 7: "discover", 8: "QTM file"}

COMP_3D, COMP_3D_NO_LABELS, COMP_6D, COMP_6D_EULER = 1, 2, 5, 6
COMP_3D_RES, COMP_3D_NO_LABELS_RES, COMP_6D_RES, COMP_6D_EULER_RES = 9, 10, 11, 12
COMP_TIMECODE, COMP_SKELETON = 17, 18
#: StreamFrames / GetCurrentFrame component names -> type numbers (the ones we encode and decode)
COMPONENT_NAMES = {"3d": COMP_3D, "3dnolabels": COMP_3D_NO_LABELS, "6d": COMP_6D, "6deuler": COMP_6D_EULER,
                   "3dres": COMP_3D_RES, "3dnolabelsres": COMP_3D_NO_LABELS_RES, "6dres": COMP_6D_RES,
                   "6deulerres": COMP_6D_EULER_RES, "timecode": COMP_TIMECODE, "skeleton": COMP_SKELETON,
                   "skeleton:global": COMP_SKELETON}

EVENT_CONNECTED, EVENT_CONNECTION_CLOSED, EVENT_CAPTURE_STARTED, EVENT_CAPTURE_STOPPED = 1, 2, 3, 4
EVENT_RT_FROM_FILE_STARTED, EVENT_RT_FROM_FILE_STOPPED, EVENT_QTM_SHUTTING_DOWN = 8, 9, 12

TIMECODE_SMPTE, TIMECODE_IRIG, TIMECODE_CAMERA = 0, 1, 2

WELCOME = "QTM RT Interface connected"
MAX_PACKET_BYTES = 16 << 20
MAX_XML_BYTES = 4 << 20

HEADER = struct.Struct("<II")
DATA_HEADER = struct.Struct("<qII")
COUNT_RATES = struct.Struct("<IHH")     # item count, 2D drop rate, 2D out-of-sync rate (3D and 6D)
COUNT = struct.Struct("<I")

_F = "<f4"
_ITEM_DTYPES = {
    COMP_3D: np.dtype([("p", _F, 3)]),
    COMP_3D_RES: np.dtype([("p", _F, 3), ("r", _F)]),
    COMP_3D_NO_LABELS: np.dtype([("p", _F, 3), ("id", "<i4")]),
    COMP_3D_NO_LABELS_RES: np.dtype([("p", _F, 3), ("id", "<i4"), ("r", _F)]),
    COMP_6D: np.dtype([("p", _F, 3), ("m", _F, 9)]),
    COMP_6D_RES: np.dtype([("p", _F, 3), ("m", _F, 9), ("r", _F)]),
    COMP_6D_EULER: np.dtype([("p", _F, 3), ("e", _F, 3)]),
    COMP_6D_EULER_RES: np.dtype([("p", _F, 3), ("e", _F, 3), ("r", _F)]),
}
SEGMENT_DTYPE = np.dtype([("id", "<i4"), ("p", _F, 3), ("q", _F, 4)])
TIMECODE_DTYPE = np.dtype([("type", "<i4"), ("hi", "<u4"), ("lo", "<u4")])


class QTMError(FormatError):
    """A QTM RT packet or parameter document that cannot be read (one line)."""

    def __init__(self, fault: str) -> None:
        super().__init__(None, fault)
        self.args = (f"QTM RT: {self.fault}",)

    def __str__(self) -> str:
        return self.args[0]


# ----- packets -------------------------------------------------------------------------------------
def encode_packet(ptype: int, payload: bytes = b"") -> bytes:
    return HEADER.pack(HEADER.size + len(payload), ptype) + payload


def encode_string(ptype: int, text: str) -> bytes:
    """An error, command or XML packet: the text NUL-terminated."""
    return encode_packet(ptype, text.encode("utf-8") + b"\0")


def packet_text(payload: bytes) -> str:
    """The string of an error, command or XML packet (NUL and what follows it dropped)."""
    return payload.split(b"\0", 1)[0].decode("utf-8", "replace")


class PacketSplitter:
    """A TCP byte stream -> whole packets ``(type, payload)``; holds at most one packet's bytes.

    A header whose size is below 8 or above ``max_packet`` means the stream cannot be followed any
    more (there is no resynchronisation marker in the protocol): :class:`QTMError`, and the
    caller drops the connection.
    """

    def __init__(self, max_packet: int = MAX_PACKET_BYTES) -> None:
        self.max_packet = int(max_packet)
        self.buf = bytearray()
        self.bytes_in = 0

    def feed(self, data: bytes) -> list[tuple[int, bytes]]:
        self.buf += data
        self.bytes_in += len(data)
        out: list[tuple[int, bytes]] = []
        buf, pos, n = self.buf, 0, len(self.buf)
        while n - pos >= HEADER.size:
            size, ptype = HEADER.unpack_from(buf, pos)
            if size < HEADER.size or size > self.max_packet:
                self.buf = bytearray()
                raise QTMError(f"packet header says {size} bytes (type {ptype}): not a QTM RT stream, "
                               f"or out of step (limit {self.max_packet} bytes)")
            if n - pos < size:
                break
            out.append((ptype, bytes(buf[pos + HEADER.size:pos + size])))
            pos += size
        if pos:
            del self.buf[:pos]
        return out

    def reset(self) -> None:
        self.buf = bytearray()


# ----- data frames ------------------------------------------------------------------------------------
@dataclass
class Skeleton:
    """One skeleton of a frame: segment ids, positions (mm) and quaternions (x, y, z, w)."""

    ids: np.ndarray         # int32[S]
    positions: np.ndarray   # float32[S, 3] mm
    quats_xyzw: np.ndarray  # float32[S, 4]


@dataclass
class QTMFrame:
    """One data packet, decoded. Arrays are None when the packet did not carry that component."""

    timestamp_us: int
    frame_number: int
    markers: np.ndarray | None = None            # float32[N, 3] mm, parameter label order, NaN unseen
    marker_residuals: np.ndarray | None = None   # float32[N] mm (3DRes only)
    unlabelled: np.ndarray | None = None         # float32[K, 3] mm
    unlabelled_ids: np.ndarray | None = None     # int32[K]
    body_positions: np.ndarray | None = None     # float32[B, 3] mm, NaN when not tracked
    body_rotations: np.ndarray | None = None     # float32[B, 9] column-major rotation matrix
    body_euler: np.ndarray | None = None         # float32[B, 3] degrees (6DEuler)
    body_residuals: np.ndarray | None = None     # float32[B] mm (6DRes / 6DEulerRes)
    skeletons: list[Skeleton] | None = None
    timecodes: np.ndarray | None = None          # TIMECODE_DTYPE[T]
    drop_rate: int = 0                           # QTM's 2D drop rate (per mille), from 3D/6D
    out_of_sync: int = 0
    skipped: list[int] = field(default_factory=list)   # component types present but not read


def _items(data: bytes, pos: int, end: int, count: int, dtype: np.dtype, what: str) -> np.ndarray:
    need = count * dtype.itemsize
    if need > end - pos:
        raise QTMError(f"{what}: {count} items need {need} bytes, the component holds {end - pos}")
    return np.frombuffer(data, dtype=dtype, count=count, offset=pos)


def _count_rates(data: bytes, pos: int, end: int, what: str) -> tuple[int, int, int]:
    if end - pos < COUNT_RATES.size:
        raise QTMError(f"{what}: component of {end - pos + 8} bytes is shorter than its header")
    return COUNT_RATES.unpack_from(data, pos)


def _read_skeletons(data: bytes, pos: int, end: int) -> list[Skeleton]:
    if end - pos < COUNT.size:
        raise QTMError("skeleton component: no skeleton count")
    (n,) = COUNT.unpack_from(data, pos)
    pos += COUNT.size
    if n > (end - pos) // COUNT.size:
        raise QTMError(f"skeleton component: {n} skeletons cannot fit in {end - pos} bytes")
    out = []
    for k in range(n):
        if end - pos < COUNT.size:
            raise QTMError(f"skeleton {k}: truncated before its segment count")
        (s,) = COUNT.unpack_from(data, pos)
        seg = _items(data, pos + COUNT.size, end, s, SEGMENT_DTYPE, f"skeleton {k}")
        pos += COUNT.size + seg.nbytes
        out.append(Skeleton(seg["id"], seg["p"], seg["q"]))
    return out


def _read_component(frame: QTMFrame, data: bytes, ctype: int, pos: int, end: int) -> None:
    if ctype in (COMP_3D, COMP_3D_RES, COMP_3D_NO_LABELS, COMP_3D_NO_LABELS_RES,
                 COMP_6D, COMP_6D_RES, COMP_6D_EULER, COMP_6D_EULER_RES):
        what = f"component {ctype}"
        n, frame.drop_rate, frame.out_of_sync = _count_rates(data, pos, end, what)
        dt = _ITEM_DTYPES[ctype]
        items = _items(data, pos + COUNT_RATES.size, end, n, dt, what)
        res = items["r"] if "r" in dt.names else None
        # (a frame may carry 6D and 6DEulerRes together: a residual once read is kept)
        if ctype in (COMP_3D, COMP_3D_RES):
            frame.markers = items["p"]
            frame.marker_residuals = res if res is not None else frame.marker_residuals
        elif ctype in (COMP_3D_NO_LABELS, COMP_3D_NO_LABELS_RES):
            frame.unlabelled, frame.unlabelled_ids = items["p"], items["id"]
        else:
            frame.body_positions = items["p"]
            frame.body_residuals = res if res is not None else frame.body_residuals
            if "m" in dt.names:
                frame.body_rotations = items["m"]
            else:
                frame.body_euler = items["e"]
    elif ctype == COMP_SKELETON:
        frame.skeletons = _read_skeletons(data, pos, end)
    elif ctype == COMP_TIMECODE:
        if end - pos < COUNT.size:
            raise QTMError("timecode component: no count")
        (n,) = COUNT.unpack_from(data, pos)
        frame.timecodes = _items(data, pos + COUNT.size, end, n, TIMECODE_DTYPE, "timecode component")
    else:
        frame.skipped.append(ctype)


def decode_data(payload: bytes) -> QTMFrame:
    """A data packet's payload (after the 8-byte packet header) -> :class:`QTMFrame`; QTMError."""
    if len(payload) < DATA_HEADER.size:
        raise QTMError(f"data packet of {len(payload) + 8} bytes is shorter than its header")
    ts, fn, nc = DATA_HEADER.unpack_from(payload, 0)
    frame = QTMFrame(int(ts), int(fn))
    pos, end = DATA_HEADER.size, len(payload)
    if nc > (end - pos) // HEADER.size:
        raise QTMError(f"frame {fn}: {nc} components cannot fit in {end - pos} bytes")
    for _ in range(nc):
        if end - pos < HEADER.size:
            raise QTMError(f"frame {fn}: truncated before a component header")
        csize, ctype = HEADER.unpack_from(payload, pos)
        if csize < HEADER.size or csize > end - pos:
            raise QTMError(f"frame {fn}: component {ctype} says {csize} bytes, {end - pos} left")
        _read_component(frame, payload, ctype, pos + HEADER.size, pos + csize)
        pos += csize
    return frame


# ----- encoding (the simulator's side) -------------------------------------------------------------
def _component(ctype: int, body: bytes) -> bytes:
    return HEADER.pack(HEADER.size + len(body), ctype) + body


def _records(dtype: np.dtype, n: int, **cols: np.ndarray) -> bytes:
    rec = np.zeros(n, dtype=dtype)
    for k, v in cols.items():
        rec[k] = v
    return rec.tobytes()


def component_3d(mm: np.ndarray, residuals: np.ndarray | None = None, drop_rate: int = 0) -> bytes:
    ctype = COMP_3D if residuals is None else COMP_3D_RES
    cols = {"p": mm} if residuals is None else {"p": mm, "r": residuals}
    return _component(ctype, COUNT_RATES.pack(len(mm), drop_rate, 0) + _records(_ITEM_DTYPES[ctype], len(mm), **cols))


def component_3d_no_labels(mm: np.ndarray, ids: np.ndarray, residuals: np.ndarray | None = None) -> bytes:
    ctype = COMP_3D_NO_LABELS if residuals is None else COMP_3D_NO_LABELS_RES
    cols = {"p": mm, "id": ids} if residuals is None else {"p": mm, "id": ids, "r": residuals}
    return _component(ctype, COUNT_RATES.pack(len(mm), 0, 0) + _records(_ITEM_DTYPES[ctype], len(mm), **cols))


def component_6d(mm: np.ndarray, rot_colmajor: np.ndarray, residuals: np.ndarray | None = None) -> bytes:
    ctype = COMP_6D if residuals is None else COMP_6D_RES
    cols = {"p": mm, "m": rot_colmajor} if residuals is None else {"p": mm, "m": rot_colmajor, "r": residuals}
    return _component(ctype, COUNT_RATES.pack(len(mm), 0, 0) + _records(_ITEM_DTYPES[ctype], len(mm), **cols))


def component_6d_euler(mm: np.ndarray, euler_deg: np.ndarray, residuals: np.ndarray | None = None) -> bytes:
    ctype = COMP_6D_EULER if residuals is None else COMP_6D_EULER_RES
    cols = {"p": mm, "e": euler_deg} if residuals is None else {"p": mm, "e": euler_deg, "r": residuals}
    return _component(ctype, COUNT_RATES.pack(len(mm), 0, 0) + _records(_ITEM_DTYPES[ctype], len(mm), **cols))


def component_skeletons(skeletons: list[Skeleton]) -> bytes:
    parts = [COUNT.pack(len(skeletons))]
    for sk in skeletons:
        n = len(sk.ids)
        parts.append(COUNT.pack(n) + _records(SEGMENT_DTYPE, n, id=sk.ids, p=sk.positions, q=sk.quats_xyzw))
    return _component(COMP_SKELETON, b"".join(parts))


def component_timecodes(codes: list[tuple[int, int, int]]) -> bytes:
    body = COUNT.pack(len(codes)) + b"".join(struct.pack("<iII", t, hi, lo) for t, hi, lo in codes)
    return _component(COMP_TIMECODE, body)


def encode_data(frame_number: int, timestamp_us: int, components: list[bytes]) -> bytes:
    """A whole data packet (header included) from encoded components."""
    body = DATA_HEADER.pack(int(timestamp_us), int(frame_number) & 0xFFFFFFFF, len(components))
    return encode_packet(PACKET_DATA, body + b"".join(components))


def smpte(frame_number: int, rate_hz: float, fps: int = 30) -> int:
    """QTM's SMPTE timecode word: hours bits 0-4, minutes 5-10, seconds 11-16, frame 17-21."""
    t = frame_number / rate_hz
    s = int(t)
    return (s // 3600 % 24) | (s // 60 % 60) << 5 | (s % 60) << 11 | (int((t - s) * fps) % fps) << 17


def smpte_text(word: int) -> str:
    return f"{word & 31:02d}:{word >> 5 & 63:02d}:{word >> 11 & 63:02d}:{word >> 17 & 31:02d}"


# ----- parameter XML ----------------------------------------------------------------------------------
@dataclass
class SkeletonDef:
    """A skeleton of the parameter XML: segments in document order with their parent index."""

    name: str
    segment_names: list[str]
    segment_ids: list[int]
    parents: list[int]                 # index into the segments, -1 for a root
    offsets_mm: np.ndarray             # float64[S, 3] Transform position, parent frame (NaN if absent)


@dataclass
class QTMParameters:
    version: str = ""
    frequency: float = 0.0
    axis_upwards: str = "+Z"
    labels: list[str] = field(default_factory=list)
    bodies: list[str] = field(default_factory=list)
    skeletons: list[SkeletonDef] = field(default_factory=list)
    has_3d: bool = False
    has_6d: bool = False


def _float(text: str | None, default: float = float("nan")) -> float:
    try:
        return float(text) if text is not None else default
    except ValueError:
        return default


MAX_SEGMENT_DEPTH = 64


def _segments(top: ET.Element, sk: dict) -> None:
    """Walk nested Segment elements (QTM 1.21+), depth first in document order, without recursion
    (a hostile document may nest deeper than Python's stack); a flat list with Parent_ID works too."""
    stack = [(seg, -1, 1) for seg in reversed(top.findall("Segment"))]
    while stack:
        seg, parent, depth = stack.pop()
        if depth > MAX_SEGMENT_DEPTH:
            raise QTMError(f"skeleton {sk['name']!r}: segments nested over {MAX_SEGMENT_DEPTH} deep")
        idx = len(sk["names"])
        sk["names"].append(seg.get("Name", f"segment{idx}"))
        try:
            sk["ids"].append(int(seg.get("ID", idx + 1)))
        except ValueError:
            raise QTMError(f"skeleton {sk['name']!r}: segment ID {seg.get('ID')!r} is not a number") from None
        sk["parent_ids"].append(seg.get("Parent_ID"))
        sk["parents"].append(parent)
        pos = seg.find("Transform/Position")
        if pos is None:
            pos = seg.find("Position")
        sk["offsets"].append([_float(pos.get(a)) if pos is not None else np.nan for a in "XYZ"])
        stack.extend((child, idx, depth + 1) for child in reversed(seg.findall("Segment")))


def _skeleton(el: ET.Element) -> SkeletonDef:
    sk = {"name": el.get("Name", ""), "names": [], "ids": [], "parents": [], "parent_ids": [], "offsets": []}
    _segments(el.find("Segments") if el.find("Segments") is not None else el, sk)
    by_id = {i: k for k, i in enumerate(sk["ids"])}
    parents = [p if pid is None else by_id.get(int(pid) if pid.lstrip("-").isdigit() else -1, -1)
               for p, pid in zip(sk["parents"], sk["parent_ids"])]
    return SkeletonDef(sk["name"], sk["names"], sk["ids"], parents,
                       np.asarray(sk["offsets"], dtype=np.float64).reshape(-1, 3))


def parse_parameters(text: str | bytes) -> QTMParameters:
    """A GetParameters reply (any subset of General, 3D, 6D, Skeleton) -> QTMParameters; QTMError."""
    if isinstance(text, bytes):
        text = packet_text(text)
    if len(text) > MAX_XML_BYTES:
        raise QTMError(f"parameter XML of {len(text)} bytes is over the {MAX_XML_BYTES} byte limit")
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise QTMError("parameter XML declares a DOCTYPE or entities: refused")
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise QTMError(f"parameter XML: {exc}") from None
    if not root.tag.startswith("QTM_Parameters"):
        raise QTMError(f"parameter XML root is <{root.tag[:40]}>, not <QTM_Parameters_Ver_...>")
    p = QTMParameters(version=root.tag.rpartition("_")[2] if "_Ver_" in root.tag else "")
    p.frequency = _float(root.findtext("General/Frequency"), 0.0)
    the3d = root.find("The_3D")
    if the3d is not None:
        p.has_3d = True
        p.axis_upwards = (the3d.findtext("AxisUpwards") or "+Z").strip()
        p.labels = [(lab.findtext("Name") or "").strip() for lab in the3d.findall("Label")]
    the6d = root.find("The_6D")
    if the6d is not None:
        p.has_6d = True
        p.bodies = [(b.findtext("Name") or "").strip() for b in the6d.findall("Body")]
    skels = root.find("Skeletons")
    if skels is not None:
        p.skeletons = [_skeleton(el) for el in skels.findall("Skeleton")]
    return p


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    el = ET.SubElement(parent, tag, {k: str(v) for k, v in attrs.items()})
    if text is not None:
        el.text = str(text)
    return el


def parameters_xml(version: str, frequency: float, axis_upwards: str = "+Z", labels: list[str] | None = None,
                   bodies: list[tuple[str, np.ndarray]] | None = None,
                   skeletons: list[SkeletonDef] | None = None, parts: tuple[str, ...] = ("all",)) -> str:
    """The XML QTM sends for ``GetParameters parts``: General, The_3D (labels), The_6D (bodies:
    name and points in mm, body frame) and Skeletons (nested segments, Transform in mm)."""
    want = {s.lower() for s in parts}
    every = "all" in want
    root = ET.Element(f"QTM_Parameters_Ver_{version}")
    if every or "general" in want:
        g = _sub(root, "General")
        _sub(g, "Frequency", f"{frequency:g}")
        _sub(g, "Capture_Time", "10")
    if every or "3d" in want:
        t = _sub(root, "The_3D")
        _sub(t, "AxisUpwards", axis_upwards)
        _sub(t, "CalibrationTime", "2026-12-06 00:00:00")
        _sub(t, "Labels", str(len(labels or [])))
        for name in labels or []:
            lab = _sub(t, "Label")
            _sub(lab, "Name", name)
            _sub(lab, "RGBColor", "ff0000")
            _sub(lab, "Trajectory_Type", "Measured")
        _sub(t, "Bones")
    if every or "6d" in want:
        s = _sub(root, "The_6D")
        _sub(s, "Bodies", str(len(bodies or [])))
        for name, pts in bodies or []:
            b = _sub(s, "Body")
            _sub(b, "Name", name)
            _sub(b, "Enabled", "true")
            _sub(b, "Color", R="0", G="255", B="0")
            _sub(b, "MaximumResidual", "10")
            _sub(b, "MinimumMarkersInBody", "3")
            points = _sub(b, "Points")
            for i, p in enumerate(np.asarray(pts, dtype=float).reshape(-1, 3)):
                _sub(points, "Point", X=f"{p[0]:.4f}", Y=f"{p[1]:.4f}", Z=f"{p[2]:.4f}", Virtual="0",
                     PhysicalId="0", Name=f"{name}_{i + 1}")
        e = _sub(s, "Euler")
        for k, v in (("First", "Roll"), ("Second", "Pitch"), ("Third", "Yaw")):
            _sub(e, k, v)
    if every or "skeleton" in want or "skeleton:global" in want:
        root_sk = _sub(root, "Skeletons")
        for sk in skeletons or []:
            el = _sub(root_sk, "Skeleton", Name=sk.name)
            _sub(el, "Solver", "Global Optimization")
            _sub(el, "Scale", "1.000000")
            holders = {-1: _sub(el, "Segments")}
            for k, (name, sid, par) in enumerate(zip(sk.segment_names, sk.segment_ids, sk.parents)):
                attrs = {"Name": name, "ID": str(sid)}
                if par >= 0:
                    attrs["Parent_ID"] = str(sk.segment_ids[par])
                seg = _sub(holders[par], "Segment", **attrs)
                _sub(seg, "Solver", "Global Optimization")
                tr = _sub(seg, "Transform")
                o = sk.offsets_mm[k]
                _sub(tr, "Position", X=f"{o[0]:.6f}", Y=f"{o[1]:.6f}", Z=f"{o[2]:.6f}")
                _sub(tr, "Rotation", X="0.000000", Y="0.000000", Z="0.000000", W="1.000000")
                holders[k] = seg
    return ET.tostring(root, encoding="unicode")
