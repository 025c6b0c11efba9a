"""What survives in damaged MCAP bytes: a chunk's records (a cut lz4 chunk decoded block by block),
the summary section, plausible record starts. Used by :mod:`.recover`; reads, never writes.

Every size a record states is checked against the bytes present before anything is allocated:
a chunk may claim at most 255 bytes of records per compressed byte (lz4's own limit) and a
summary at most what lies between its start and the footer.
"""
from __future__ import annotations

import io
import mmap
import struct
import zlib
from dataclasses import dataclass, field

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, Message, MessageIndex, Schema, Statistics

from .errors import BagError
from .framing import unpack_frames
from .reader import READ_ERRORS

REC = struct.Struct("<BQ")  # opcode, record length
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length
_FOOTER = struct.Struct("<BQQQI")  # opcode, length 20, summary start, summary offset start, crc
MAGIC_LEN = 8
OPCODES = {int(o) for o in Opcode}
_LZ4_MAX_RATIO = 255  # lz4 never expands a byte to more than 255
_PIECE = 16 * 1024  # compressed bytes fed to the decoder at a time
_MAX_SUMMARY = 256 << 20


@dataclass
class ChunkContent:
    """What one chunk record yielded."""

    start_ns: int
    end_ns: int
    uncompressed_size: int
    records: list = field(default_factory=list)  # Schema / Channel / Message in stored order
    whole: bool = False  # every byte decoded and the CRC (when written) agrees
    decoded: int = 0  # bytes of records recovered
    why: str = ""  # why it is not whole


def _decompress(compression: str, data: bytes, limit: int) -> tuple[bytes, str]:
    """(decoded prefix of at most ``limit`` bytes, "" or why decoding stopped early).

    Fed piece by piece so a cut or damaged stream still gives every block before the fault.
    """
    if compression == "":
        return bytes(data[:limit]), ""
    if compression == "lz4":
        import lz4.frame

        dec = lz4.frame.LZ4FrameDecompressor()
        call = lambda piece, room: dec.decompress(piece, max_length=room)  # noqa: E731
    elif compression == "zstd":
        import zstandard

        zobj = zstandard.ZstdDecompressor().decompressobj()
        call = lambda piece, room: zobj.decompress(piece)  # noqa: E731
    else:
        return b"", f"unknown compression {compression!r}"
    out = bytearray()
    for at in range(0, len(data), _PIECE):
        try:
            out += call(data[at:at + _PIECE], limit + 1 - len(out))
        except Exception as exc:  # noqa: BLE001 - lz4 / zstd raise their own errors on bad bytes
            return bytes(out[:limit]), f"{compression} data damaged ({type(exc).__name__})"
        if len(out) > limit:
            return bytes(out[:limit]), f"{compression} data decode to more than the chunk's stated size"
    return bytes(out), ""


def message_ok(m: Message) -> bool:
    """The message's data splits into the frames its own lengths promise (framing.unpack_frames)."""
    try:
        unpack_frames(m.data)
        return True
    except BagError:
        return False


def parse_records(buf: bytes) -> tuple[list, int]:
    """(Schema / Channel / Message records, bytes used) from the front of ``buf``; stops at the
    first record cut short or unreadable. Other record kinds are skipped."""
    out: list = []
    pos = 0
    while pos + REC.size <= len(buf):
        opcode, length = REC.unpack_from(buf, pos)
        body_at = pos + REC.size
        if length > len(buf) - body_at:
            break
        stream = ReadDataStream(io.BytesIO(buf[body_at:body_at + length]))
        try:
            if opcode == Opcode.SCHEMA:
                out.append(Schema.read(stream))
            elif opcode == Opcode.CHANNEL:
                out.append(Channel.read(stream))
            elif opcode == Opcode.MESSAGE:
                out.append(Message.read(stream, length))
            elif opcode not in OPCODES:
                break
        except READ_ERRORS:
            break
        pos = body_at + length
    return out, pos


def read_chunk(body: bytes, *, cut: bool) -> ChunkContent | None:
    """Decode a chunk record's body (``cut``: the file ends inside it). None when even its fixed
    header is not there. A whole chunk failing its CRC yields no records (which byte is wrong
    is unknown); a cut one yields the records of every block that decodes, each message checked
    against its own frame lengths."""
    if len(body) < _CHUNK_FIXED.size:
        return None
    t0, t1, usize, crc, clen = _CHUNK_FIXED.unpack_from(body)
    out = ChunkContent(t0, t1, usize)
    at = _CHUNK_FIXED.size
    if clen > 16 or len(body) < at + clen + 8:
        out.why = "chunk header damaged"
        return out
    compression = body[at:at + clen].decode("ascii", "replace")
    (dlen,) = struct.unpack_from("<Q", body, at + clen)
    data = body[at + clen + 8:at + clen + 8 + dlen]
    if not cut and len(data) != dlen:
        out.why = "chunk lengths disagree"
        return out
    bound = dlen if compression == "" else _LZ4_MAX_RATIO * dlen + 64
    if usize > bound:
        out.why = f"chunk claims {usize} bytes of records from {dlen} stored"
        return out
    payload, why = _decompress(compression, data, usize)
    if not cut and not why:
        if len(payload) != usize or (crc and zlib.crc32(payload) != crc):
            out.why = "chunk failed its checksum"
            return out
        out.records, out.decoded = parse_records(payload)
        out.whole = out.decoded == usize
        out.why = "" if out.whole else "chunk records damaged"
        return out
    if not cut:
        out.why = why
        return out
    recs, used = parse_records(payload)
    out.records = [r for r in recs if not isinstance(r, Message) or message_ok(r)]
    out.decoded = used
    out.why = "the file ends inside this chunk"
    return out


@dataclass
class Summary:
    """Schema, Channel and Statistics records of an intact summary section."""

    schemas: list[Schema] = field(default_factory=list)
    channels: list[Channel] = field(default_factory=list)
    statistics: Statistics | None = None
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)


def read_summary(mm, size: int) -> Summary | None:
    """The summary section named by the footer at the end of ``mm`` (a bytes-like of ``size``
    bytes), when footer and summary are intact (the footer's CRC, when written, agrees)."""
    foot_at = size - MAGIC_LEN - _FOOTER.size
    if foot_at < MAGIC_LEN:
        return None
    opcode, length, start, _ofs, crc = _FOOTER.unpack_from(mm, foot_at)
    if opcode != Opcode.FOOTER or length != 20 or not (MAGIC_LEN <= start < foot_at) \
            or foot_at - start > _MAX_SUMMARY:
        return None
    # the CRC covers the summary and the footer up to its CRC field
    if crc and zlib.crc32(bytes(mm[start:foot_at + _FOOTER.size - 4])) != crc:
        return None
    out = Summary()
    pos = start
    while pos + REC.size <= foot_at:
        op, ln = REC.unpack_from(mm, pos)
        if ln > foot_at - pos - REC.size:
            return None
        stream = ReadDataStream(io.BytesIO(bytes(mm[pos + REC.size:pos + REC.size + ln])))
        try:
            if op == Opcode.SCHEMA:
                out.schemas.append(Schema.read(stream))
            elif op == Opcode.CHANNEL:
                out.channels.append(Channel.read(stream))
            elif op == Opcode.STATISTICS:
                out.statistics = Statistics.read(stream)
            elif op == Opcode.CHUNK_INDEX:
                out.chunk_indexes.append(ChunkIndex.read(stream))
        except READ_ERRORS:
            return None
        pos += REC.size + ln
    return out


def message_index_count(body: bytes) -> int | None:
    """Messages listed by a MessageIndex record body (None when unreadable)."""
    try:
        return len(MessageIndex.read(ReadDataStream(io.BytesIO(body))).records)
    except READ_ERRORS:
        return None


def chunk_at(mm, off: int, size: int) -> bool:
    """True when the bytes at ``off`` frame a plausible chunk record (lengths agree to the byte)."""
    if off + REC.size + _CHUNK_FIXED.size > size:
        return False
    length = struct.unpack_from("<Q", mm, off + 1)[0]
    if length < _CHUNK_FIXED.size + 8 or off + REC.size + length > size:
        return False
    *_, clen = _CHUNK_FIXED.unpack_from(mm, off + REC.size)
    if clen > 16:
        return False
    at = off + REC.size + _CHUNK_FIXED.size
    if bytes(mm[at:at + clen]) not in (b"", b"lz4", b"zstd"):
        return False
    data_len = struct.unpack_from("<Q", mm, at + clen)[0]
    return _CHUNK_FIXED.size + clen + 8 + data_len == length


def next_chunk(mm, start: int, size: int) -> int | None:
    """Offset of the next plausible chunk record at or after ``start`` (its CRC is checked when read)."""
    off = start
    while True:
        off = mm.find(bytes([Opcode.CHUNK]), off, size)
        if off < 0:
            return None
        if chunk_at(mm, off, size):
            return off
        off += 1


def open_map(f) -> mmap.mmap | None:
    try:
        return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (ValueError, OSError):
        return None
