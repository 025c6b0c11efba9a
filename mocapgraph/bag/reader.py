"""Reading bags: a checked opening (clear faults, never a traceback), summaries and messages.

`BagReader` opens a complete MCAP file through its index. Anything that is not a usable bag is
reported as a `BagError` naming the file and the fault: not MCAP (with a hint to ``bag convert``
when it looks like C3D/TRC/BVH/CSV), empty, truncated or unfinished (with the hint to run
``mocapgraph bag recover``). Topics whose type or schema version this build does not know are
listed with ``known=False`` and the reason; they can still be copied but not decoded.
"""
from __future__ import annotations

import io
import json
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Metadata
from mcap.stream_reader import MAGIC_SIZE, StreamReader

from ..messages import Envelope, Message, decode_envelope, decode_payload
from ..messages.codec import DecodeError, header_sender, header_seq, header_stream
from ..messages.registry import UnknownTypeError, lookup
from ..messages.sequence import StreamTracker
from .errors import BagError
from .framing import MESSAGE_ENCODING, header_of, unpack_frames
from .writer import META_INFO, META_LOSSES

MCAP_MAGIC = b"\x89MCAP0\r\n"
RECOVER_HINT = "run 'mocapgraph bag recover {path}' to save every complete chunk into a new bag"
# lz4 raises RuntimeError, struct raises struct.error, truncated records EndOfFile (an McapError)
READ_ERRORS = (McapError, struct.error, RuntimeError, ValueError, EOFError, OSError, KeyError, MemoryError)


@dataclass
class TopicInfo:
    """One topic of a bag."""

    topic: str
    type_name: str
    schema_version: int
    encoding: str
    latched: bool
    count: int = 0
    first_ns: int = 0
    last_ns: int = 0
    known: bool = True
    problem: str = ""

    @property
    def duration_s(self) -> float:
        return (self.last_ns - self.first_ns) / 1e9

    @property
    def rate_hz(self) -> float:
        """Mean rate over the topic's own span (0 for a single message)."""
        return (self.count - 1) / self.duration_s if self.count > 1 and self.last_ns > self.first_ns else 0.0


@dataclass
class BagSummary:
    """What `bag info` prints: span, topics, metadata and recorded losses."""

    path: Path
    size_bytes: int
    start_ns: int
    end_ns: int
    count: int
    chunks: int
    compression: str
    library: str
    topics: dict[str, TopicInfo]
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    losses: dict[str, int] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        return max(0, self.end_ns - self.start_ns) / 1e9


@dataclass
class ScanReport:
    """Per topic and sender: sequence gaps found in the stored headers, and long time gaps."""

    seq_gaps: dict[str, int]
    time_gaps: dict[str, list[tuple[float, float]]]  # topic -> [(at s from its first message, length s)]
    periods_s: dict[str, float]  # median interval per topic


class RawMessage:
    """One stored message: topic, stamps and the stored frames (decoded on demand)."""

    __slots__ = ("topic", "log_ns", "publish_ns", "data", "channel")

    def __init__(self, topic: str, log_ns: int, publish_ns: int, data: bytes, channel: Channel) -> None:
        self.topic = topic
        self.log_ns = log_ns
        self.publish_ns = publish_ns
        self.data = data
        self.channel = channel

    def frames(self, topic: str | None = None) -> list[bytes | memoryview]:
        """Bus frames ready to send (topic frame first; ``topic`` renames it)."""
        return unpack_frames(self.data, (topic or self.topic).encode() + b"\0")

    def envelope(self) -> Envelope:
        return decode_envelope([self.topic.encode() + b"\0", header_of(self.data), b""])

    def decode(self) -> tuple[Envelope, Message]:
        """Envelope and message; BagError when the type is unknown here or the bytes are bad."""
        frames = self.frames()
        try:
            env = decode_envelope(frames)
            cls = lookup(env.type_name)
            return env, decode_payload(cls, env, frames)
        except UnknownTypeError:
            raise BagError(None, f"topic {self.topic!r} holds type {self.channel.metadata.get('type')!r}, "
                                 "unknown to this mocapgraph version") from None
        except DecodeError as exc:
            raise BagError(None, f"topic {self.topic!r}: {exc}") from None


def sniff_kind(head: bytes, path: Path) -> str:
    """A guess at what a non-MCAP file is, for the hint."""
    text = head[:64].lstrip()
    if len(head) >= 2 and head[1] == 0x50:
        return "C3D"
    if text.startswith(b"PathFileType"):
        return "TRC"
    if text.upper().startswith(b"HIERARCHY"):
        return "BVH"
    if path.suffix.lower() in (".csv", ".txt"):
        return "CSV"
    if head.startswith(b"\x89MCAP"):
        return "MCAP of another major version"
    return ""


def check_bag_file(path: str | Path) -> Path:
    """The path of a file that starts and ends like a complete MCAP file, or BagError saying why not."""
    p = Path(path)
    if not p.exists():
        raise BagError(p, "no such file")
    if p.is_dir():
        raise BagError(p, "is a folder, not a bag file (split bags: give one of the .mcap files)")
    try:
        size = p.stat().st_size
        with open(p, "rb") as f:
            head = f.read(64)
            if size >= MAGIC_SIZE * 2:
                f.seek(-MAGIC_SIZE, io.SEEK_END)
                tail = f.read(MAGIC_SIZE)
            else:
                tail = b""
    except OSError as exc:
        raise BagError(p, f"cannot read ({exc.strerror or exc})") from None
    if size == 0:
        raise BagError(p, "empty file (0 bytes), not a bag", "a recorder that never received a message writes nothing")
    if not head.startswith(MCAP_MAGIC):
        kind = sniff_kind(head, p)
        hint = ""
        if kind in ("C3D", "TRC", "BVH", "CSV"):
            hint = f"it looks like {kind}: turn it into a bag with 'mocapgraph bag convert {p} -o OUT.mcap'"
        raise BagError(p, "not an MCAP file (bags are MCAP files written by 'mocapgraph bag record' or "
                          "'bag convert')" + (f"; {kind}?" if kind and not hint else ""), hint)
    if tail != MCAP_MAGIC:
        raise BagError(p, f"truncated or unfinished: the file ({size} bytes) ends without the MCAP footer "
                          "(the recorder was killed, the disk filled, or the copy was cut short)",
                       RECOVER_HINT.format(path=p), damaged=True)
    return p


class BagReader:
    """A complete bag opened for reading. Use as a context manager or call close()."""

    def __init__(self, path: str | Path) -> None:
        self.path = check_bag_file(path)
        self._f = open(self.path, "rb")
        try:
            self._r = SeekingReader(self._f)
            self._mcap_summary = self._r.get_summary()
            self._header = self._r.get_header()
        except READ_ERRORS as exc:
            self._f.close()
            raise BagError(self.path, f"damaged MCAP structure ({type(exc).__name__}: {exc})",
                           RECOVER_HINT.format(path=self.path), damaged=True) from None
        if self._mcap_summary is None:
            self._f.close()
            raise BagError(self.path, "has no summary section (not indexed)", RECOVER_HINT.format(path=self.path),
                           damaged=True)
        self._channels = dict(self._mcap_summary.channels)
        self._summary: BagSummary | None = None

    # ----- structure ------------------------------------------------------------------------------
    def topic_infos(self) -> dict[str, TopicInfo]:
        """Topics with type, schema version and whether this build can decode them (no scan)."""
        s = self._mcap_summary
        counts = s.statistics.channel_message_counts if s.statistics else {}
        out: dict[str, TopicInfo] = {}
        for cid, ch in sorted(self._channels.items()):
            schema = s.schemas.get(ch.schema_id)
            tname = ch.metadata.get("type") or (schema.name if schema else "")
            try:
                version = int(ch.metadata.get("schema_version", "0"))
            except ValueError:
                version = 0
            info = out.get(ch.topic)
            if info is None:
                info = out[ch.topic] = TopicInfo(ch.topic, tname, version, ch.message_encoding,
                                                 ch.metadata.get("latched") == "true")
            elif info.type_name != tname:
                info.problem = f"holds more than one type ({info.type_name}, {tname})"
            info.count += counts.get(cid, 0)
            if ch.message_encoding != MESSAGE_ENCODING:
                info.known = False
                info.problem = f"message encoding {ch.message_encoding!r} is not mocapgraph's ({MESSAGE_ENCODING})"
                continue
            try:
                cls = lookup(tname)
                if cls.version != version:
                    info.known = False
                    info.problem = (f"{tname} schema version {version} in the bag, this mocapgraph knows "
                                    f"version {cls.version}")
            except UnknownTypeError:
                info.known = False
                info.problem = f"type {tname!r} is unknown to this mocapgraph version (schema kept in the bag)"
        return out

    def schemas(self) -> dict[str, dict]:
        """Stored JSON Schemas by type name."""
        out = {}
        for sc in self._mcap_summary.schemas.values():
            try:
                out[sc.name] = json.loads(sc.data) if sc.encoding == "jsonschema" else {}
            except ValueError:
                out[sc.name] = {}
        return out

    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (the last one wins, so recorded losses are the final counts)."""
        out: dict[str, dict[str, str]] = {}
        try:
            for m in self._r.iter_metadata():
                out[m.name] = dict(m.metadata)
        except READ_ERRORS as exc:
            raise self._damaged(exc) from None
        return out

    def _damaged(self, exc: Exception) -> BagError:
        return BagError(self.path, f"damaged data ({type(exc).__name__}: {exc})", RECOVER_HINT.format(path=self.path),
                        damaged=True)

    def summary(self) -> BagSummary:
        """Span, counts, topics, metadata, recorded losses (from the index, no scan)."""
        if self._summary is not None:
            return self._summary
        s = self._mcap_summary
        topics = self.topic_infos()
        # per-topic first/last time from the chunk indexes' per-channel message indexes is costly;
        # chunk ranges bound them well enough for a summary and `scan` gives exact values.
        by_channel_first: dict[int, int] = {}
        by_channel_last: dict[int, int] = {}
        for ci in s.chunk_indexes:
            for cid in ci.message_index_offsets:
                by_channel_first[cid] = min(by_channel_first.get(cid, ci.message_start_time), ci.message_start_time)
                by_channel_last[cid] = max(by_channel_last.get(cid, ci.message_end_time), ci.message_end_time)
        for cid, ch in self._channels.items():
            t = topics[ch.topic]
            if cid in by_channel_first:
                t.first_ns = by_channel_first[cid] if not t.first_ns else min(t.first_ns, by_channel_first[cid])
                t.last_ns = max(t.last_ns, by_channel_last[cid])
        meta = self.metadata()
        losses = {k: int(v) for k, v in meta.get(META_LOSSES, {}).items() if v.isdigit()}
        st = s.statistics
        comps = sorted({ci.compression or "none" for ci in s.chunk_indexes})
        self._summary = BagSummary(
            path=self.path, size_bytes=self.path.stat().st_size,
            start_ns=st.message_start_time if st else 0, end_ns=st.message_end_time if st else 0,
            count=st.message_count if st else 0, chunks=len(s.chunk_indexes),
            compression=",".join(comps) or "none", library=self._header.library,
            topics=topics, metadata=meta, losses=losses)
        return self._summary

    # ----- messages ------------------------------------------------------------------------------
    def messages(self, topics: Iterable[str] | None = None, start_ns: int | None = None,
                 end_ns: int | None = None) -> Iterator[RawMessage]:
        """Stored messages in file (= recorded) order, optionally by topic and log-time window
        [start_ns, end_ns). Damage found while reading raises BagError."""
        want = None if topics is None else set(topics)
        it = self._r.iter_messages(topics=None if want is None else sorted(want), log_time_order=False,
                                   starting_at=start_ns, ending_before=end_ns)
        while True:
            try:
                _schema, ch, m = next(it)
            except StopIteration:
                return
            except READ_ERRORS as exc:
                raise self._damaged(exc) from None
            yield RawMessage(ch.topic, m.log_time, m.publish_time, m.data, ch)

    def publish_span(self, topics: Iterable[str] | None = None) -> tuple[int, int]:
        """First and last publish stamp (the sender's clock), reading only the first and last chunk."""
        s = self.summary()
        first = next(iter(self.messages(topics)), None)
        if first is None:
            return s.start_ns, s.end_ns
        last = max((m.publish_ns or m.log_ns for m in self.messages(topics, start_ns=s.end_ns)),
                   default=s.end_ns)
        return first.publish_ns or first.log_ns, last

    def decoded(self, topic: str, start_ns: int | None = None, end_ns: int | None = None
                ) -> Iterator[tuple[Envelope, Message]]:
        """Envelope and message of every message of ``topic``."""
        info = self.topic_infos().get(topic)
        if info is None:
            raise BagError(self.path, f"has no topic {topic!r} (topics: {', '.join(sorted(self.topic_infos()))})")
        if not info.known:
            raise BagError(self.path, f"topic {topic!r}: {info.problem}")
        for raw in self.messages([topic], start_ns, end_ns):
            try:
                yield raw.decode()
            except BagError as exc:
                raise BagError(self.path, exc.fault) from None

    def scan(self, progress: Callable[[int], None] | None = None, gap_factor: float = 3.0) -> ScanReport:
        """Read every header: sequence gaps per topic, long time gaps (> gap_factor x median).

        Per-topic spans (and so rates) are updated from publish stamps, exact and free of the
        recorder's receive delays."""
        streams: dict[tuple[str, str], StreamTracker] = {}
        seq_gaps: dict[str, int] = {}
        times: dict[str, list[int]] = {}
        first: dict[str, int] = {}
        last: dict[str, int] = {}
        for i, raw in enumerate(self.messages()):
            if raw.channel.message_encoding != MESSAGE_ENCODING:
                continue
            try:
                head = header_of(raw.data)
                seq, stream = header_seq(head), header_stream(head)
                sender = header_sender(head).decode(errors="replace")
            except (struct.error, IndexError):
                continue
            tracker = streams.get((raw.topic, sender))
            if tracker is None:
                tracker = streams[(raw.topic, sender)] = StreamTracker()
            before = tracker.gaps
            tracker.take(stream, seq, raw.publish_ns)
            if tracker.gaps != before:   # (a forged jump found out later is taken back)
                seq_gaps[raw.topic] = seq_gaps.get(raw.topic, 0) + tracker.gaps - before
            t = raw.publish_ns or raw.log_ns  # the sender's clock: free of the recorder's own delays
            times.setdefault(raw.topic, []).append(t)
            first.setdefault(raw.topic, t)
            last[raw.topic] = t
            if progress is not None and i % 4096 == 0:
                progress(i)
        summary = self.summary()
        periods: dict[str, float] = {}
        tgaps: dict[str, list[tuple[float, float]]] = {}
        for topic, ts in times.items():
            info = summary.topics.get(topic)
            if info is not None:
                info.first_ns, info.last_ns = first[topic], last[topic]
            if len(ts) < 3:
                continue
            d = np.diff(np.asarray(ts, np.int64))
            med = float(np.median(d))
            periods[topic] = med / 1e9
            if med <= 0:
                continue
            big = np.flatnonzero(d > gap_factor * med)
            tgaps[topic] = [((ts[k] - ts[0]) / 1e9, d[k] / 1e9) for k in big[:50]]
        return ScanReport(seq_gaps, tgaps, periods)

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_latest(reader: BagReader, topic: str) -> Message | None:
    """The last message of a (latched) topic, decoded; None when the topic is absent."""
    out = None
    if topic not in reader.topic_infos():
        return None
    for _env, msg in reader.decoded(topic):
        out = msg
    return out
