"""Recovering a damaged, truncated or unfinished bag: every readable message into a new bag.

A recorder killed mid-session leaves a file without summary and footer, often ending in a
partly written chunk; a bad disk or a copy flips bytes anywhere. Here the file is walked record
by record from the start (length-prefixed records, skipping damage to the next plausible chunk),
and written to a new, indexed bag with the original metadata plus a ``mocapgraph.recovery`` record:

* every whole chunk that passes its CRC, wherever it lies;
* the readable front of a chunk the file ends inside (lz4 decoded block by block, each message
  checked against its own frame lengths);
* channels and schemas from wherever they survive: the summary section (when its CRC agrees),
  any chunk, any top-level record. A first pass collects them when there is no usable summary,
  so a damaged first chunk (where a recorder writes every channel record) costs only its own
  messages.

Loss is reported as counted when the bag says how many messages it held (the summary's
Statistics, or the MessageIndex records following a damaged chunk), else estimated from sizes
and marked so. Messages the recorder held in memory and never wrote leave no trace (at most one
flush period, 0.25 s by default).
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from .errors import BagError
from .reader import MCAP_MAGIC, READ_ERRORS, sniff_kind
from .salvage import (OPCODES, REC, ChunkContent, Summary, message_index_count, message_ok, next_chunk,
                      open_map, read_chunk, read_summary)
from .writer import PROFILE, mocapgraph_version


@dataclass
class RecoveryReport:
    """What `recover` saved and what it could not."""

    source: Path
    output: Path
    saved: int = 0
    saved_by_topic: dict[str, int] = field(default_factory=dict)
    chunks_saved: int = 0
    chunks_bad: int = 0  # damaged chunks and damaged regions skipped, plus a cut last chunk
    chunks_partial: int = 0  # cut chunks whose readable front was saved
    salvaged: int = 0  # messages saved from cut chunks
    lost_estimate: int = 0  # messages lost (counted when lost_counted, else estimated from sizes)
    lost_counted: bool = False
    lost_span_s: float = 0.0  # time span of the damaged chunks
    lost_by_topic: dict[str, int] = field(default_factory=dict)  # when the bag's statistics say
    orphans: int = 0  # readable messages whose channel record survives nowhere
    tail_bytes: int = 0  # bytes after the last whole record
    channels_from: str = ""  # "summary" or "records"
    start_ns: int = 0
    end_ns: int = 0
    was_complete: bool = False
    reason: str = ""

    def text(self) -> str:
        span = (self.end_ns - self.start_ns) / 1e9 if self.saved else 0.0
        part = (f"; {self.salvaged} of them from the readable front of {self.chunks_partial} cut chunk(s)"
                if self.chunks_partial else "")
        lines = [f"saved {self.saved} messages ({self.chunks_saved} whole chunks{part}, {span:.2f} s) "
                 f"to {self.output}"]
        for t, n in sorted(self.saved_by_topic.items()):
            lines.append(f"  {t}: {n}")
        if self.was_complete:
            lines.append("the source was a complete bag; nothing was lost")
            return "\n".join(lines)
        if self.lost_estimate or self.chunks_bad:
            how = ("counted from the bag's own index" if self.lost_counted
                   else "estimated from the damaged chunks' sizes")
            lost = f"lost: {'' if self.lost_counted else 'about '}{self.lost_estimate} messages ({how})"
            if self.chunks_bad:
                lost += (f" in {self.chunks_bad} damaged or cut chunk(s) or region(s) spanning "
                         f"{self.lost_span_s:.2f} s")
        else:
            lost = "lost: no written message"
        if self.orphans:
            lost += f"; {self.orphans} of them readable but with no surviving channel record"
        lost_topics = [f"  lost {t}: {n}" for t, n in sorted(self.lost_by_topic.items()) if n]
        lines.append(lost + (f"; {self.tail_bytes} bytes at the end were unusable" if self.tail_bytes else ""))
        lines += lost_topics
        if self.reason:
            lines.append(f"why: {self.reason}")
        lines.append("messages the recorder had not flushed when it stopped are not in the file "
                     "(at most one flush period, 0.25 s by default)")
        return "\n".join(lines)


def recover(src: str | Path, dst: str | Path | None = None, *, compression: str = "lz4",
            progress: Callable[[int, int], None] | None = None, force: bool = False) -> RecoveryReport:
    """Write a new complete bag from every readable message of ``src``; returns what was saved and lost.

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
        mm = open_map(f)
        if mm is None:
            raise BagError(src, "cannot map the file to read it")
        try:
            summary = read_summary(mm, size)
            known = _known_records(mm, size, summary, rep)
            with open(tmp, "wb") as out:
                w = Writer(out, compression=CompressionType.LZ4 if compression == "lz4" else CompressionType.NONE,
                           chunk_size=1 << 20)
                _Copier(w, rep, known, summary).run(_walk(mm, size), size, progress)
                w.finish()
            if rep.saved == 0:
                raise BagError(src, f"nothing to recover: no readable message in its {size} bytes"
                               + (f" ({rep.reason})" if rep.reason else ""))
            os.replace(tmp, dst)
        finally:
            mm.close()
            if tmp.exists():
                tmp.unlink()
    return rep


# ----- the walk -------------------------------------------------------------------------------------
# events: ("rec", pos, opcode, record) | ("chunk", pos, ChunkContent, nbytes) | ("index", pos, count)
#         | ("damaged", pos, start, end) | ("end", pos, tail_bytes, why)
Event = tuple


def _walk(mm, size: int) -> Iterator[Event]:
    """Every record of the file in order, skipping damage to the next plausible chunk."""
    pos = len(MCAP_MAGIC)
    while True:
        if pos + REC.size > size:
            yield ("end", size, size - pos, "the file ends inside a record header" if size > pos else "")
            return
        opcode, length = REC.unpack_from(mm, pos)
        if opcode not in OPCODES or length > size - pos - REC.size:
            nxt = next_chunk(mm, pos + 1, size)
            if nxt is not None:  # damage in the middle: skip to the next intact-looking chunk
                yield ("damaged", nxt, pos, nxt)
                pos = nxt
                continue
            if opcode == Opcode.CHUNK:  # a chunk the file ends inside
                content = read_chunk(bytes(mm[pos + REC.size:size]), cut=True)
                if content is not None:
                    yield ("chunk", size, content, size - pos)
                yield ("end", size, 0 if content is not None else size - pos,
                       "the file ends inside a chunk (the recorder stopped while writing it)")
            else:
                yield ("end", size, size - pos, f"the file ends inside a record (opcode 0x{opcode:02x})")
            return
        body = bytes(mm[pos + REC.size:pos + REC.size + length])
        nxt = pos + REC.size + length
        if opcode == Opcode.CHUNK:
            content = read_chunk(body, cut=False)
            if content is None:
                content = ChunkContent(0, 0, 0, why="chunk header damaged")
            yield ("chunk", nxt, content, REC.size + length)
            pos = nxt
            continue
        if opcode == Opcode.MESSAGE_INDEX:
            n = message_index_count(body)
            if n is not None:
                yield ("index", nxt, n)
                pos = nxt
                continue
        try:
            rec = _parse(opcode, body, length)
        except READ_ERRORS as exc:
            skip = next_chunk(mm, pos + 1, size)
            yield ("damaged", skip or size, pos, skip or size)
            if skip is None:
                yield ("end", size, size - pos, f"a damaged record at byte {pos} ({type(exc).__name__})")
                return
            pos = skip
            continue
        yield ("rec", nxt, opcode, rec)
        if opcode == Opcode.FOOTER:
            return
        pos = nxt


def _parse(opcode: int, body: bytes, length: int):
    stream = ReadDataStream(io.BytesIO(body))
    kinds = {Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata,
             Opcode.ATTACHMENT: Attachment}
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, length)
    if opcode in kinds:
        return kinds[opcode].read(stream)
    return None  # DataEnd, indexes, statistics...: rebuilt by the writer


@dataclass
class _Known:
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)

    def take(self, rec) -> None:
        if isinstance(rec, Schema):
            self.schemas.setdefault(rec.id, rec)
        elif isinstance(rec, Channel):
            self.channels.setdefault(rec.id, rec)


def _known_records(mm, size: int, summary: Summary | None, rep: RecoveryReport) -> _Known:
    """Schemas and channels from the summary, or, without one, from a first pass over every record."""
    known = _Known()
    if summary is not None and summary.channels:
        for r in summary.schemas + summary.channels:
            known.take(r)
        rep.channels_from = "summary"
        return known
    for ev in _walk(mm, size):
        if ev[0] == "rec":
            known.take(ev[3])
        elif ev[0] == "chunk":
            for r in ev[2].records:
                known.take(r)
    rep.channels_from = "records"
    return known


class _Copier:
    """Second pass: writes what the walk yields and keeps the books of what was lost."""

    def __init__(self, w: Writer, rep: RecoveryReport, known: _Known, summary: Summary | None) -> None:
        self.w, self.rep, self.known, self.summary = w, rep, known, summary
        self.schema_map: dict[int, int] = {}
        self.channel_map: dict[int, int] = {}
        self.saved_by_channel: dict[int, int] = {}
        self.meta: list[Metadata] = []
        self.started = False
        self.footer = False
        # to estimate what damaged chunks held: compressed bytes of whole chunks, then uncompressed
        # bytes and messages of whole chunks and of the decoded fronts of cut ones
        self.sizes = [0, 0, 0]
        self.whole_msgs = 0
        self.lost: list[dict] = []  # per damaged chunk / region: bytes, uncompressed bytes, counted
        self.last_lost: dict | None = None  # the damaged chunk MessageIndex records may count

    def start(self, profile: str = PROFILE) -> None:
        if not self.started:
            self.w.start(profile=profile or PROFILE, library=f"mocapgraph/{mocapgraph_version()} (recovered)")
            self.started = True

    def channel(self, cid: int) -> int | None:
        if cid in self.channel_map:
            return self.channel_map[cid]
        c = self.known.channels.get(cid)
        if c is None:
            return None
        sid = 0
        if c.schema_id and c.schema_id in self.known.schemas:
            if c.schema_id not in self.schema_map:
                s = self.known.schemas[c.schema_id]
                self.schema_map[s.id] = self.w.register_schema(s.name, s.encoding, s.data)
            sid = self.schema_map[c.schema_id]
        self.channel_map[cid] = self.w.register_channel(c.topic, c.message_encoding, sid, dict(c.metadata))
        return self.channel_map[cid]

    def message(self, m: Message) -> bool:
        cid = self.channel(m.channel_id)
        if cid is None:
            self.rep.orphans += 1
            return False
        self.w.add_message(cid, m.log_time, m.data, m.publish_time, m.sequence)
        rep = self.rep
        rep.saved += 1
        self.saved_by_channel[m.channel_id] = self.saved_by_channel.get(m.channel_id, 0) + 1
        topic = self.known.channels[m.channel_id].topic
        rep.saved_by_topic[topic] = rep.saved_by_topic.get(topic, 0) + 1
        rep.start_ns = m.log_time if rep.saved == 1 else min(rep.start_ns, m.log_time)
        rep.end_ns = max(rep.end_ns, m.log_time)
        return True

    def chunk(self, c: ChunkContent, nbytes: int) -> None:
        self.start()
        saved = sum(self.message(r) for r in c.records if isinstance(r, Message))
        if c.whole:
            self.rep.chunks_saved += 1
            self.sizes[0] += nbytes
            self.sizes[1] += c.uncompressed_size
            self.sizes[2] += saved
            self.whole_msgs += saved
            self.last_lost = None
            return
        self.rep.chunks_bad += 1
        self.rep.lost_span_s += max(0, c.end_ns - c.start_ns) / 1e9
        self.rep.reason = c.why
        if saved:
            self.rep.chunks_partial += 1
            self.rep.salvaged += saved
            self.sizes[1] += c.decoded  # the decoded front tells bytes per message as well
            self.sizes[2] += saved
        self.last_lost = {"bytes": nbytes, "usize": max(c.uncompressed_size - c.decoded, 0), "counted": None,
                          "kept": saved}
        self.lost.append(self.last_lost)

    def run(self, events: Iterator[Event], size: int, progress) -> None:
        last_report = 0
        for ev in events:
            kind, pos = ev[0], ev[1]
            if kind == "rec":
                self.record(ev[2], ev[3])
            elif kind == "chunk":
                self.chunk(ev[2], ev[3])
            elif kind == "index":
                if self.last_lost is not None:  # the index of a damaged chunk says what it held
                    self.last_lost["counted"] = (self.last_lost["counted"] or 0) + ev[2]
            elif kind == "damaged":
                self.rep.chunks_bad += 1
                self.rep.reason = f"damaged bytes {ev[2]}..{ev[3]} were skipped"
                self.last_lost = {"bytes": ev[3] - ev[2], "usize": 0, "counted": None, "kept": 0}
                self.lost.append(self.last_lost)
                self.last_lost = None  # a region's index records are not told apart from the next chunk's
            elif kind == "end":
                self.rep.tail_bytes = ev[2]
                self.rep.reason = ev[3] or self.rep.reason
            if progress is not None and pos - last_report > (1 << 20):
                progress(pos, size)
                last_report = pos
        self.finish(size, progress)

    def record(self, opcode: int, rec) -> None:
        if opcode == Opcode.HEADER:
            self.start(rec.profile)
        elif opcode == Opcode.MESSAGE:
            self.start()
            if message_ok(rec):
                self.message(rec)
        elif opcode == Opcode.METADATA:
            self.start()
            self.meta.append(rec)
        elif opcode == Opcode.ATTACHMENT:
            self.start()
            self.w.add_attachment(rec.create_time, rec.log_time, rec.name, rec.media_type, rec.data)
        elif opcode == Opcode.FOOTER:
            self.footer = True

    def finish(self, size: int, progress) -> None:
        rep = self.rep
        self.count_losses()
        rep.was_complete = self.footer and not self.lost and not rep.orphans and not rep.tail_bytes
        self.start()
        for m in self.meta:
            self.w.add_metadata(m.name, dict(m.metadata))
        self.w.add_metadata("mocapgraph.recovery", {
            "source": str(rep.source), "saved": str(rep.saved), "chunks_saved": str(rep.chunks_saved),
            "chunks_bad": str(rep.chunks_bad), "chunks_partial": str(rep.chunks_partial),
            "lost_estimate": str(rep.lost_estimate), "lost_counted": str(rep.lost_counted).lower(),
            "orphans": str(rep.orphans), "tail_bytes": str(rep.tail_bytes),
            "reason": rep.reason or ("complete" if rep.was_complete else "")})
        if progress is not None:
            progress(size, size)

    def count_losses(self) -> None:
        """Messages lost: the summary's Statistics when it has them (exact), else per damaged
        chunk its MessageIndex count (exact) or its size over the saved chunks' bytes per message."""
        rep = self.rep
        stats = self.summary.statistics if self.summary is not None else None
        if stats is not None and stats.message_count >= rep.saved:
            rep.lost_estimate = stats.message_count - rep.saved
            rep.lost_counted = True
            for cid, n in stats.channel_message_counts.items():
                c = self.known.channels.get(cid)
                if c is not None and n > self.saved_by_channel.get(cid, 0):
                    rep.lost_by_topic[c.topic] = n - self.saved_by_channel.get(cid, 0)
            return
        comp, unc, msgs = self.sizes
        lost, counted = rep.orphans, True  # orphans: readable, so counted
        for region in self.lost:
            if region["counted"] is not None:
                lost += max(region["counted"] - region["kept"], 0)
                continue
            counted = False
            if msgs and region["usize"] and unc:
                lost += max(1, round(region["usize"] / (unc / msgs)))
            elif self.whole_msgs and comp:
                lost += max(1, round(region["bytes"] / (comp / self.whole_msgs)))
        rep.lost_estimate = lost
        rep.lost_counted = counted
