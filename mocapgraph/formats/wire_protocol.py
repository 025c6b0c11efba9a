"""Marker-device wire protocols (serial line and UDP), encoders and streaming decoders.

A marker device (a camera system's bridge, a microcontroller, a simulator) sends one frame of
3-D marker positions per message, in one of two protocols. Both carry the same content:

* frame   - the device's frame counter, unsigned, +1 per captured frame (gaps = drops);
* t_us    - the device's capture time in microseconds, unsigned 64-bit, any epoch, monotonic;
* n       - number of markers in the frame, 0..MAX_MARKERS (4096), fixed order per device
            (the device's marker layout names them);
* x y z   - per marker, millimetres, in the device's own frame (the reader node maps it to the
            world frame from the device configuration); a missing marker is NaN.

Decoders return :class:`WireFrame` with positions in METRES (mm / 1000) and the time in
nanoseconds (t_us * 1000).

Text protocol (ASCII, for serial consoles and hand debugging)
--------------------------------------------------------------
One frame per line, fields separated by one or more spaces or tabs, line ended by LF
(a CR before it is ignored)::

    F <frame> <t_us> <n> <x1> <y1> <z1> ... <xn> <yn> <zn>[ *<crc>]\\n

* ``F`` is a capital F followed by a space.
* frame, t_us, n: decimal unsigned integers.
* coordinates: decimal numbers as C's ``printf("%.3f")`` or ``%g`` writes them (``-12.5``,
  ``1e3``); ``nan`` (any case) for a missing marker. Infinities are invalid.
* optional checksum: a space, ``*`` and 8 hexadecimal digits: the CRC-32 (IEEE 802.3,
  as zlib.crc32 / Ethernet) of the line's bytes from ``F`` up to, not including, the space
  before ``*``. Receivers verify it when present.
* Lines starting with ``#`` are comments (device banner, status) and are ignored.
* A line longer than MAX_LINE_BYTES (65536) is invalid.

Example: ``F 1203 5012000 2 105.250 -20.000 1012.125 nan nan nan *9A0C33F1``

Binary protocol (little-endian, for UDP datagrams and fast serial links)
------------------------------------------------------------------------
=======  ======  ==========================================================
offset   bytes   field
=======  ======  ==========================================================
0        4       magic ``4D 47 46 A5`` ("MGF" then 0xA5)
4        1       version, 1
5        1       flags, 0 (reserved; receivers reject other values)
6        2       n, uint16, number of markers (<= 4096)
8        4       frame, uint32
12       8       t_us, uint64
20       12 n    n x (x, y, z) float32 IEEE-754, millimetres, NaN if missing
20+12n   4       CRC-32 (as zlib.crc32) of bytes [0, 20 + 12 n)
=======  ======  ==========================================================

A frame is 24 + 12 n bytes. On UDP send one frame per datagram; on a byte stream frames are
sent back to back. No padding, no terminator.

Decoding a stream
-----------------
:class:`TextDecoder` and :class:`BinaryDecoder` are fed arbitrary chunks (``feed(bytes)``),
return the frames completed so far, and never raise on bad input: anything that is not a
valid frame is skipped and counted in ``decoder.stats`` (``rejected_bytes``,
``rejected_frames``, ``crc_errors``). They resynchronise on the next ``F`` (text; also
inside a line with a garbage prefix) or the next magic (binary; after a bad candidate they
move on by one byte only, so a real frame hidden behind a false start is still found).
"""
from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

MAGIC = b"MGF\xa5"
VERSION = 1
MAX_MARKERS = 4096
MAX_LINE_BYTES = 65536
_HEAD = struct.Struct("<4sBBHIQ")  # magic, version, flags, n, frame, t_us
_HEAD_SIZE = _HEAD.size  # 20
_U32 = (1 << 32) - 1
_U64 = (1 << 64) - 1


@dataclass
class WireFrame:
    """One decoded device frame: positions in metres [n, 3] (NaN missing), device time ns."""

    frame: int
    device_time_ns: int
    positions: np.ndarray
    protocol: str = ""

    @property
    def t_us(self) -> int:
        return self.device_time_ns // 1000


@dataclass
class DecoderStats:
    """What a decoder has seen. ``rejected_bytes`` counts bytes thrown away that were not
    part of a frame, a comment or an empty line."""

    frames: int = 0
    rejected_frames: int = 0  # frame candidates that failed (bad field, count, CRC...)
    rejected_bytes: int = 0  # bytes discarded as not part of any valid frame
    crc_errors: int = 0
    comments: int = 0
    bytes_in: int = 0
    buffered_bytes: int = 0
    last_error: str = ""
    errors: dict[str, int] = field(default_factory=dict)

    def _reject(self, why: str, frames: int = 1) -> None:
        self.rejected_frames += frames
        self.last_error = why
        key = why.split(":")[0]
        self.errors[key] = self.errors.get(key, 0) + 1


# ---------------------------------------------------------------------------------------
# encoders
# ---------------------------------------------------------------------------------------
def _mm(positions_m: np.ndarray) -> np.ndarray:
    p = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3) * 1000.0
    if p.shape[0] > MAX_MARKERS:
        raise ValueError(f"at most {MAX_MARKERS} markers per frame")
    if np.isinf(p).any():
        raise ValueError("positions must be finite or NaN")
    return p


def encode_text(frame: int, t_us: int, positions_m: np.ndarray, *, checksum: bool = True,
                decimals: int = 3) -> bytes:
    """One text-protocol line (bytes, LF-terminated) for positions in metres [n, 3]."""
    p = _mm(positions_m)
    if not (0 <= frame <= _U64 and 0 <= t_us <= _U64):
        raise ValueError("frame and t_us must be unsigned 64-bit")
    fmt = f"{{:.{decimals}f}}"
    coords = " ".join("nan" if math.isnan(v) else fmt.format(v) for v in p.ravel().tolist())
    body = f"F {int(frame)} {int(t_us)} {p.shape[0]}" + (f" {coords}" if coords else "")
    raw = body.encode("ascii")
    if checksum:
        raw += b" *%08X" % zlib.crc32(raw)
    return raw + b"\n"


def encode_binary(frame: int, t_us: int, positions_m: np.ndarray) -> bytes:
    """One binary-protocol frame for positions in metres [n, 3]."""
    p = _mm(positions_m)
    if not (0 <= frame <= _U32 and 0 <= t_us <= _U64):
        raise ValueError("frame must fit uint32 and t_us uint64")
    head = _HEAD.pack(MAGIC, VERSION, 0, p.shape[0], int(frame), int(t_us))
    body = head + p.astype("<f4").tobytes()
    return body + struct.pack("<I", zlib.crc32(body))


# ---------------------------------------------------------------------------------------
# text decoder
# ---------------------------------------------------------------------------------------
def _parse_text(line: bytes) -> tuple[WireFrame | None, str]:
    """Parse one line that starts with b"F " (no LF). (frame, "") or (None, reason)."""
    body = line
    star = line.rfind(b" *")
    if star >= 0 and len(line) - star == 10:
        body = line[:star]
        try:
            want = int(line[star + 2:], 16)
        except ValueError:
            return None, "checksum: not hex"
        if zlib.crc32(body) != want:
            return None, "crc: text checksum mismatch"
    tok = body.split()
    if len(tok) < 4 or tok[0] != b"F":
        return None, "field: too few fields"
    try:
        frame, t_us, n = int(tok[1]), int(tok[2]), int(tok[3])
    except ValueError:
        return None, "field: frame/t_us/n not integers"
    if frame < 0 or t_us < 0 or not 0 <= n <= MAX_MARKERS or t_us > _U64:
        return None, "field: frame/t_us/n out of range"
    if len(tok) != 4 + 3 * n:
        return None, f"count: n={n} but {len(tok) - 4} coordinates"
    try:
        xyz = np.array([float(t) for t in tok[4:]], dtype=np.float64)
    except ValueError:
        return None, "field: coordinate not a number"
    if np.isinf(xyz).any():
        return None, "field: infinite coordinate"
    return WireFrame(frame, t_us * 1000, xyz.reshape(n, 3) / 1000.0, "text"), ""


class _StreamDecoder:
    """Buffer and counters shared by the decoders."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self.stats = DecoderStats()

    def _take(self, data: bytes) -> DecoderStats:
        self.stats.bytes_in += len(data)
        self._buf += data
        return self.stats


class TextDecoder(_StreamDecoder):
    """Streaming decoder for the text protocol; ``feed`` never raises on bad input."""

    def feed(self, data: bytes) -> list[WireFrame]:
        """Add bytes; return the frames whose lines are now complete."""
        st = self._take(data)
        out: list[WireFrame] = []
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            line = bytes(self._buf[:nl])
            del self._buf[:nl + 1]
            self._line(line, nl + 1, out)
        if len(self._buf) > MAX_LINE_BYTES:  # keep only a tail that could still be a frame
            cut = len(self._buf) - MAX_LINE_BYTES
            st.rejected_bytes += cut
            st._reject("length: line too long", 0)
            del self._buf[:cut]
        st.buffered_bytes = len(self._buf)
        return out

    def _line(self, line: bytes, size: int, out: list[WireFrame]) -> None:
        st = self.stats
        if line.endswith(b"\r"):
            line = line[:-1]
        stripped = line.strip()
        if not stripped:
            return  # empty lines between frames are harmless
        if stripped.startswith(b"#"):
            st.comments += 1
            return
        if len(line) > MAX_LINE_BYTES:
            st.rejected_bytes += size
            st._reject("length: line too long")
            return
        # Try every "F " start, leftmost first: garbage may precede a real frame on its line.
        pos = 0 if line.startswith(b"F ") else line.find(b"F ")
        reason = "field: no 'F ' frame start"
        while pos >= 0:
            frame, reason = _parse_text(line[pos:])
            if frame is not None:
                st.frames += 1
                st.rejected_bytes += pos
                if pos:
                    st._reject("garbage: bytes before a frame on its line", 0)
                out.append(frame)
                return
            pos = line.find(b"F ", pos + 1)
        st.rejected_bytes += size
        if reason.startswith(("crc", "checksum")):
            st.crc_errors += 1
        st._reject(reason)

    def flush(self) -> list[WireFrame]:
        """Treat buffered bytes as a final line (end of stream without LF)."""
        if not self._buf:
            return []
        return self.feed(b"\n")


# ---------------------------------------------------------------------------------------
# binary decoder
# ---------------------------------------------------------------------------------------
class BinaryDecoder(_StreamDecoder):
    """Streaming decoder for the binary protocol; ``feed`` never raises on bad input."""

    def feed(self, data: bytes) -> list[WireFrame]:
        """Add bytes (any chunking, or one UDP datagram); return completed frames."""
        st = self._take(data)
        out: list[WireFrame] = []
        buf = self._buf
        while True:
            start = buf.find(MAGIC)
            if start < 0:
                # keep the longest tail that could be the beginning of a magic
                keep = min(len(buf), len(MAGIC) - 1)
                while keep and not MAGIC.startswith(bytes(buf[len(buf) - keep:])):
                    keep -= 1
                st.rejected_bytes += len(buf) - keep
                del buf[:len(buf) - keep]
                break
            if start:
                st.rejected_bytes += start
                del buf[:start]
            if len(buf) < _HEAD_SIZE:
                break
            _, version, flags, n, frame, t_us = _HEAD.unpack_from(buf, 0)
            if version != VERSION or flags != 0 or n > MAX_MARKERS:
                st._reject("header: bad version/flags/n")
                st.rejected_bytes += 1
                del buf[:1]
                continue
            size = _HEAD_SIZE + 12 * n + 4
            if len(buf) < size:
                break
            crc = struct.unpack_from("<I", buf, size - 4)[0]
            if zlib.crc32(memoryview(buf)[: size - 4]) != crc:
                st.crc_errors += 1
                st._reject("crc: binary frame checksum mismatch")
                st.rejected_bytes += 1
                del buf[:1]
                continue
            xyz = np.frombuffer(bytes(buf[_HEAD_SIZE:size - 4]), dtype="<f4").astype(np.float64)
            del buf[:size]
            if np.isinf(xyz).any():
                st._reject("field: infinite coordinate")
                st.rejected_bytes += size
                continue
            st.frames += 1
            out.append(WireFrame(frame, t_us * 1000, xyz.reshape(n, 3) / 1000.0, "binary"))
        st.buffered_bytes = len(buf)
        return out

    def flush(self) -> list[WireFrame]:
        """End of stream: whatever is buffered is discarded and counted as rejected."""
        self.stats.rejected_bytes += len(self._buf)
        if self._buf:
            self.stats._reject("truncated: stream ended inside a frame")
        self._buf.clear()
        self.stats.buffered_bytes = 0
        return []


def make_decoder(protocol: str) -> TextDecoder | BinaryDecoder:
    """Decoder for "text" or "binary"."""
    if protocol == "text":
        return TextDecoder()
    if protocol == "binary":
        return BinaryDecoder()
    raise ValueError(f"unknown wire protocol {protocol!r} (use 'text' or 'binary')")
