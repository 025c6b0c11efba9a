"""Recovering a truncated or unfinished bag: copy every whole, intact chunk into a new bag.

A recorder killed mid-session leaves a file without summary and footer, often ending in a
partly written chunk. The MCAP index is at the end, so the seeking reader sees nothing; here the
file is walked record by record from the start (length-prefixed records), every chunk that is
whole and passes its CRC is decoded, and its schemas, channels and messages (stamps and sequence
kept) are written to a new, indexed bag with the original metadata plus a ``mocapgraph.recovery``
record. A partial chunk at the end is counted (its header gives its time span and size, from
which the number of messages lost is estimated); messages the recorder held in memory and never
wrote leave no trace (at most one flush period, 0.25 s by default).
"""
from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Chunk, Header, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from .errors import BagError
from .reader import MCAP_MAGIC, READ_ERRORS, sniff_kind
from .writer import PROFILE, mocapgraph_version

_REC = struct.Struct("<BQ")
_CHUNK_HEAD = struct.Struct("<QQQI")  # start, end, uncompressed size, crc


@dataclass
class RecoveryReport:
    """What `recover` saved and what it could not."""

    source: Path
    output: Path
    saved: int = 0
    saved_by_topic: dict[str, int] = field(default_factory=dict)
    chunks_saved: int = 0
    chunks_bad: int = 0
    lost_estimate: int = 0  # messages in the partial/damaged chunks (estimated from their size)
    lost_span_s: float = 0.0  # time span of the partial/damaged chunks
    tail_bytes: int = 0  # bytes after the last whole record
    start_ns: int = 0
    end_ns: int = 0
    was_complete: bool = False
    reason: str = ""

    def text(self) -> str:
        span = (self.end_ns - self.start_ns) / 1e9 if self.saved else 0.0
        lines = [f"saved {self.saved} messages ({self.chunks_saved} chunks, {span:.2f} s) to {self.output}"]
        for t, n in sorted(self.saved_by_topic.items()):
            lines.append(f"  {t}: {n}")
        if self.was_complete:
            lines.append("the source was a complete bag; nothing was lost")
        else:
            lost = f"lost: about {self.lost_estimate} messages" if self.chunks_bad else "lost: no written message"
            if self.chunks_bad:
                lost += f" in {self.chunks_bad} partial or damaged chunk(s) spanning {self.lost_span_s:.2f} s"
            lines.append(lost + (f"; {self.tail_bytes} bytes at the end were unusable" if self.tail_bytes else ""))
            lines.append(f"why: {self.reason}" if self.reason else "")
            lines.append("messages the recorder had not flushed when it stopped are not in the file "
                         "(at most one flush period, 0.25 s by default)")
        return "\n".join(x for x in lines if x)


def recover(src: str | Path, dst: str | Path | None = None, *, compression: str = "lz4",
            progress: Callable[[int, int], None] | None = None, force: bool = False) -> RecoveryReport:
    """Write a new complete bag from every whole chunk of ``src``; returns what was saved and lost.

    An existing ``dst`` is kept unless ``force``; a source with no message to save is an error
    and leaves no output. The new bag is written beside ``dst`` and renamed into place at the end.
    """
    src = Path(src)
    if not src.is_file():
        raise BagError(src, "no such file")
    dst = Path(dst) if dst else src.with_name(src.stem + ".recovered.mcap")
    if dst.resolve() == src.resolve():
        raise BagError(dst, "the recovered bag must not overwrite its source")
    if dst.exists() and not force:
        raise BagError(dst, "exists; pass --force to overwrite it")
    size = src.stat().st_size
    rep = RecoveryReport(src, dst)
    tmp = dst.with_name(f".{dst.name}.part-{os.getpid()}")
    with open(src, "rb") as f:
        magic = f.read(len(MCAP_MAGIC))
        if size == 0:
            raise BagError(src, "empty file (0 bytes): nothing to recover")
        if magic != MCAP_MAGIC:
            kind = sniff_kind(magic, src)
            raise BagError(src, "not an MCAP file: nothing to recover" + (f" (it looks like {kind})" if kind else ""))
        try:
            with open(tmp, "wb") as out:
                w = Writer(out, compression=CompressionType.LZ4 if compression == "lz4" else CompressionType.NONE,
                           chunk_size=1 << 20)
                _walk(f, size, w, rep, progress)
                w.finish()
            if rep.saved == 0:
                raise BagError(src, f"nothing to recover: no whole chunk with a message in its {size} bytes"
                               + (f" ({rep.reason})" if rep.reason else ""))
            os.replace(tmp, dst)
        finally:
            if tmp.exists():
                tmp.unlink()
    return rep


def _walk(f, size: int, w: Writer, rep: RecoveryReport, progress) -> None:
    schema_map: dict[int, int] = {}
    channel_map: dict[int, int] = {}
    channels: dict[int, Channel] = {}
    pending_schemas: dict[int, Schema] = {}
    header_seen = False
    started = False
    meta_records: list[Metadata] = []
    saved_bytes = 0  # uncompressed bytes of saved chunks, to estimate lost message counts
    pos = f.tell()
    last_report = 0

    def start(profile: str = PROFILE, library: str = "") -> None:
        nonlocal started
        if not started:
            w.start(profile=profile or PROFILE, library=f"mocapgraph/{mocapgraph_version()} (recovered)")
            started = True

    def add_schema(s: Schema) -> None:
        if s.id not in schema_map:
            schema_map[s.id] = w.register_schema(s.name, s.encoding, s.data)

    def add_channel(c: Channel) -> None:
        if c.id not in channel_map:
            sid = 0
            if c.schema_id:
                if c.schema_id not in schema_map and c.schema_id in pending_schemas:
                    add_schema(pending_schemas[c.schema_id])
                sid = schema_map.get(c.schema_id, 0)
            channel_map[c.id] = w.register_channel(c.topic, c.message_encoding, sid, dict(c.metadata))
            channels[c.id] = c

    def add_message(m: Message) -> None:
        cid = channel_map.get(m.channel_id)
        if cid is None:
            return  # a message whose channel record was in a lost chunk
        w.add_message(cid, m.log_time, m.data, m.publish_time, m.sequence)
        rep.saved += 1
        topic = channels[m.channel_id].topic
        rep.saved_by_topic[topic] = rep.saved_by_topic.get(topic, 0) + 1
        rep.start_ns = m.log_time if rep.saved == 1 else min(rep.start_ns, m.log_time)
        rep.end_ns = max(rep.end_ns, m.log_time)

    saved_compressed = 0  # compressed bytes of saved chunks, to estimate what a damaged region held

    def lose_region(nbytes: int, why: str) -> None:
        rep.chunks_bad += 1
        rep.reason = why
        if saved_compressed and rep.saved:
            rep.lost_estimate += max(1, round(nbytes / (saved_compressed / rep.saved)))

    while True:
        rec_start = pos
        head = f.read(_REC.size)
        if len(head) < _REC.size:
            rep.tail_bytes = len(head)
            if head:
                rep.reason = rep.reason or "the file ends inside a record header"
            break
        opcode, length = _REC.unpack(head)
        if opcode not in _OPCODES or length > size - pos - _REC.size:
            nxt = _resync(f, rec_start + 1, size)
            if nxt is not None:  # damage in the middle: skip to the next intact chunk
                lose_region(nxt - rec_start, f"damaged bytes {rec_start}..{nxt} were skipped")
                f.seek(nxt)
                pos = nxt
                continue
            # a record cut short by the end of the file
            rep.tail_bytes = size - pos
            f.seek(pos + _REC.size)
            body = f.read(min(length, 64))
            if opcode == Opcode.CHUNK and len(body) >= _CHUNK_HEAD.size:
                t0, t1, usize, _crc = _CHUNK_HEAD.unpack_from(body)
                rep.chunks_bad += 1
                rep.lost_span_s += max(0, t1 - t0) / 1e9
                rep.lost_estimate += _estimate(usize, saved_bytes, rep.saved)
                rep.reason = "the file ends inside a chunk (the recorder stopped while writing it)"
            else:
                rep.reason = rep.reason or f"the file ends inside a record (opcode 0x{opcode:02x})"
            break
        body = f.read(length)
        pos += _REC.size + length
        if progress is not None and pos - last_report > (1 << 20):
            progress(pos, size)
            last_report = pos
        stream = ReadDataStream(io.BytesIO(body))
        try:
            if opcode == Opcode.HEADER:
                header_seen = True
                h = Header.read(stream)
                start(h.profile, h.library)
            elif opcode == Opcode.SCHEMA:
                start()
                sc = Schema.read(stream)
                pending_schemas[sc.id] = sc
                add_schema(sc)
            elif opcode == Opcode.CHANNEL:
                start()
                add_channel(Channel.read(stream))
            elif opcode == Opcode.MESSAGE:
                start()
                add_message(Message.read(stream, length))
            elif opcode == Opcode.CHUNK:
                start()
                chunk = Chunk.read(stream)
                try:
                    records = breakup_chunk(chunk, validate_crc=True)
                except READ_ERRORS:
                    rep.chunks_bad += 1
                    rep.lost_span_s += max(0, chunk.message_end_time - chunk.message_start_time) / 1e9
                    rep.lost_estimate += _estimate(chunk.uncompressed_size, saved_bytes, rep.saved)
                    rep.reason = "a chunk failed its checksum or would not decompress"
                    continue
                for r in records:
                    if isinstance(r, Schema):
                        pending_schemas[r.id] = r
                        add_schema(r)
                    elif isinstance(r, Channel):
                        add_channel(r)
                    elif isinstance(r, Message):
                        add_message(r)
                rep.chunks_saved += 1
                saved_bytes += chunk.uncompressed_size
                saved_compressed += length
            elif opcode == Opcode.METADATA:
                start()
                meta_records.append(Metadata.read(stream))
            elif opcode == Opcode.ATTACHMENT:
                start()
                a = Attachment.read(stream)
                w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
            elif opcode == Opcode.FOOTER:
                rep.was_complete = rep.chunks_bad == 0
                break
            # DataEnd, indexes, statistics and summary records are rebuilt by the writer
        except READ_ERRORS as exc:
            nxt = _resync(f, rec_start + 1, size)
            if nxt is not None:
                lose_region(nxt - rec_start, f"a damaged record at byte {rec_start} ({type(exc).__name__}); "
                                             f"skipped to byte {nxt}")
                f.seek(nxt)
                pos = nxt
                continue
            rep.reason = f"a damaged record at byte {rec_start} ({type(exc).__name__})"
            rep.tail_bytes = size - rec_start
            break
    if not header_seen:
        rep.reason = rep.reason or "no MCAP header record"
    start()
    for m in meta_records:
        w.add_metadata(m.name, dict(m.metadata))
    w.add_metadata("mocapgraph.recovery", {
        "source": str(rep.source), "saved": str(rep.saved), "chunks_saved": str(rep.chunks_saved),
        "chunks_bad": str(rep.chunks_bad), "lost_estimate": str(rep.lost_estimate),
        "tail_bytes": str(rep.tail_bytes), "reason": rep.reason or ("complete" if rep.was_complete else "")})
    if progress is not None:
        progress(size, size)


_OPCODES = {int(o) for o in Opcode}
_CHUNK_FIXED = struct.Struct("<QQQII")  # start, end, uncompressed size, crc, compression length


def _chunk_at(mm, off: int, size: int) -> bool:
    """True when the bytes at ``off`` frame a plausible chunk record (lengths agree to the byte)."""
    if off + _REC.size + _CHUNK_FIXED.size > size:
        return False
    length = struct.unpack_from("<Q", mm, off + 1)[0]
    if length < _CHUNK_FIXED.size + 8 or off + _REC.size + length > size:
        return False
    *_, clen = _CHUNK_FIXED.unpack_from(mm, off + _REC.size)
    if clen > 16:
        return False
    at = off + _REC.size + _CHUNK_FIXED.size
    if bytes(mm[at:at + clen]) not in (b"", b"lz4", b"zstd"):
        return False
    data_len = struct.unpack_from("<Q", mm, at + clen)[0]
    return _CHUNK_FIXED.size + clen + 8 + data_len == length


def _resync(f, start: int, size: int) -> int | None:
    """Offset of the next plausible chunk record at or after ``start`` (its CRC is checked when read)."""
    import mmap

    try:
        mm = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (ValueError, OSError):
        return None
    try:
        off = start
        while True:
            off = mm.find(bytes([Opcode.CHUNK]), off, size)
            if off < 0:
                return None
            if _chunk_at(mm, off, size):
                return off
            off += 1
    finally:
        mm.close()


def _estimate(uncompressed: int, saved_bytes: int, saved_count: int) -> int:
    if saved_count and saved_bytes:
        return max(1, round(uncompressed / (saved_bytes / saved_count)))
    return 0
