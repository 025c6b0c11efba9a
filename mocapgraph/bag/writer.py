"""Writing bags: MCAP files of mocapgraph messages, stored byte for byte as they travelled.

Layout of a bag written here (see ``FORMAT.md``):

- one Schema record per message type (encoding ``jsonschema``, data = ``Message.json_schema()``),
- one Channel per topic (message encoding ``mocapgraph/frames-v1``, metadata ``type``,
  ``schema_version``, ``latched``),
- Message records: ``log_time`` = when the recorder received it (converted files: the capture
  stamp), ``publish_time`` = the original publisher's stamp, ``sequence`` = the low 32 bits of the
  bus sequence number; ``data`` = the frames (:mod:`.framing`), whose header keeps the full
  sequence number, the capture stamp and the publish stamp,
- Metadata ``mocapgraph`` (version, host, time, graph file, node params, command) at the start and
  ``mocapgraph.losses`` (messages lost per topic, from sequence numbers) whenever it changes and
  at the end.

Chunks are lz4-compressed (or not) and closed by :meth:`BagWriter.flush`, which a recorder calls
every 0.25 s so that a killed recorder loses at most that much (``bag recover`` saves the rest).
"""
from __future__ import annotations

import json
import platform
import time
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Mapping, Sequence

from mcap.writer import CompressionType, Writer

from ..messages import Envelope, Message, decode_envelope, encode
from ..messages.codec import DecodeError
from ..messages.registry import UnknownTypeError, lookup
from ..bus.file_places import PathRefused, own_folder_path
from .errors import BagError
from .framing import MESSAGE_ENCODING, pack_frames

PROFILE = "mocapgraph"
META_INFO = "mocapgraph"
META_LOSSES = "mocapgraph.losses"
COMPRESSIONS = {"lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def mocapgraph_version() -> str:
    try:
        from importlib.metadata import version

        return version("mocapgraph")
    except Exception:  # noqa: BLE001 - an uninstalled checkout still records
        return "unknown"


def base_metadata(writer: str, **extra: Any) -> dict[str, str]:
    """The ``mocapgraph`` metadata record: who wrote the bag, where and when."""
    meta = {
        "writer": writer,
        "mocapgraph_version": mocapgraph_version(),
        "host": platform.node(),
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "framing": MESSAGE_ENCODING,
    }
    for k, v in extra.items():
        meta[k] = v if isinstance(v, str) else json.dumps(v)
    return meta


def schema_bytes(type_name: str, version: int) -> tuple[bytes, bool]:
    """JSON Schema of a type as this build knows it; a stub (known False) for a foreign type."""
    try:
        cls = lookup(type_name)
        if cls.version == version:
            return json.dumps(cls.json_schema(), separators=(",", ":")).encode(), True
    except UnknownTypeError:
        pass
    stub = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": type_name,
            "x-mocapgraph-version": version,
            "description": "type not known to the mocapgraph version that recorded it; frames stored as received"}
    return json.dumps(stub).encode(), False


class BagWriter:
    """Writes one bag (or a series of split files) of mocapgraph messages.

    path: output file; with splitting, files are ``<stem>_000.mcap``, ``<stem>_001.mcap``...
    compression: "lz4" or "none".
    chunk_kb: chunk size that closes a chunk early (flush() closes one anyway).
    split_mb / split_s: start a new file after this many MB / seconds of log time (0: never).
    on_exists: "overwrite", "rename" (first free <stem>_<n>: a respawned recorder never destroys
        the bag of its previous life) or "error".
        Each split file is complete on its own: schemas, channels, metadata, and the last
        message of every latched topic again at its start.
    """

    def __init__(self, path: str | Path, *, compression: str = "lz4", chunk_kb: int = 512,
                 split_mb: float = 0.0, split_s: float = 0.0, metadata: Mapping[str, str] | None = None,
                 on_exists: str = "overwrite") -> None:
        if compression not in COMPRESSIONS:
            raise BagError(path, f"compression {compression!r} is not one of {sorted(COMPRESSIONS)}")
        self.base = _free_path(Path(path), on_exists)
        self.compression = compression
        self.chunk_bytes = int(chunk_kb * 1024)
        self.split_bytes = int(split_mb * 1e6)
        self.split_ns = int(split_s * 1e9)
        self.metadata = dict(metadata or base_metadata("BagWriter"))
        self.paths: list[Path] = []
        self.count = 0
        self.count_by_topic: dict[str, int] = {}
        self.losses: dict[str, int] = {}
        self._losses_written: dict[str, int] = {}
        self._latched: dict[str, tuple[list, int, int, int]] = {}  # topic -> (frames, log, pub, seq)
        self._file = None
        self._w: Writer | None = None
        self.failed = ""  # why writing stopped (disk full...); '' while it works
        self._in_file = self._safe_in_file = 0  # messages in the open file; of them, flushed to the OS
        self._open_next()

    # ----- files --------------------------------------------------------------------------------
    def _next_path(self) -> Path:
        if not (self.split_bytes or self.split_ns):
            return self.base
        suffix = self.base.suffix or ".mcap"
        return self.base.with_name(f"{self.base.stem}_{len(self.paths):03d}{suffix}")

    def _open_next(self) -> None:
        path = self._next_path()
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # a regular file in the folder named (a symlink planted there to elsewhere, a device or a fifo: no)
            self._file = open(own_folder_path(path, "bag"), "wb")
        except PathRefused as exc:
            raise BagError(path, str(exc)) from None
        except OSError as exc:
            raise BagError(path, f"cannot write ({exc.strerror or exc})") from None
        self.paths.append(path)
        self._in_file = self._safe_in_file = 0
        self._w = Writer(self._file, chunk_size=self.chunk_bytes, compression=COMPRESSIONS[self.compression])
        self._w.start(profile=PROFILE, library=f"mocapgraph/{mocapgraph_version()}")
        self._w.add_metadata(META_INFO, {**self.metadata, "split_index": str(len(self.paths) - 1)})
        self._schemas: dict[tuple[str, int], int] = {}
        self._channels: dict[tuple[str, str, int], int] = {}
        self._file_first_log: int | None = None
        self._since_size_check = 0
        self._losses_written = {}
        for topic, (frames, log_ns, pub_ns, seq) in list(self._latched.items()):
            self._add(topic, frames, decode_envelope(frames), log_ns, pub_ns, seq, count=False)

    def _rotate(self) -> None:
        self._finish_file()
        self._open_next()

    def _failure(self, exc: OSError) -> BagError:
        """Stop writing after ``exc`` (disk full, folder gone): the open file is closed as it is (what
        reached the disk stays, ``bag recover`` reads it), removed when none of its messages did."""
        path = self.paths[-1]
        if not self.failed:
            kept = self.count - (self._in_file - self._safe_in_file)
            why = f"cannot write ({exc.strerror or exc})"
            self.failed = (f"{why}; {max(0, kept)} messages written before are kept in {', '.join(map(str, self.paths))} "
                           "('mocapgraph bag recover' gives it its index)" if self._safe_in_file or len(self.paths) > 1
                           else f"{why}; nothing reached the disk (no file left behind)")
            try:
                self._file.close()  # (its buffered rest cannot be written: the disk is full)
            except OSError:
                pass
            if not self._safe_in_file:
                path.unlink(missing_ok=True)   # nothing of it reached the disk: no empty bag left behind
                self.paths.pop()
            self._w = None
        return BagError(path, self.failed)

    def _finish_file(self) -> None:
        if self._w is None:
            return
        try:
            self._write_losses(force=True)
            self._w.finish()
            self._file.close()
        except OSError as exc:
            raise self._failure(exc) from None
        self._w = None

    # ----- records --------------------------------------------------------------------------------
    def _channel(self, topic: str, env: Envelope) -> int:
        key = (topic, env.type_name, env.schema_version)
        cid = self._channels.get(key)
        if cid is None:
            skey = (env.type_name, env.schema_version)
            sid = self._schemas.get(skey)
            if sid is None:
                data, _ = schema_bytes(*skey)
                sid = self._schemas[skey] = self._w.register_schema(env.type_name, "jsonschema", data)
            cid = self._channels[key] = self._w.register_channel(
                topic, MESSAGE_ENCODING, sid,
                {"type": env.type_name, "schema_version": str(env.schema_version),
                 "latched": "true" if env.latched else "false"})
        return cid

    def _add(self, topic: str, frames: Sequence, env: Envelope, log_ns: int, pub_ns: int, seq: int,
             count: bool = True) -> None:
        cid = self._channel(topic, env)
        self._w.add_message(cid, log_ns, pack_frames(frames), pub_ns, seq & 0xFFFFFFFF)
        if count:
            self.count += 1
            self._in_file += 1
            self.count_by_topic[topic] = self.count_by_topic.get(topic, 0) + 1

    def write_frames(self, frames: Sequence[bytes | memoryview], log_ns: int | None = None,
                     env: Envelope | None = None) -> None:
        """Store one bus message as received. ``log_ns`` defaults to now; ``env`` saves a decode.
        BagError (one line) once the disk refuses (see ``failed``)."""
        if self.failed:
            raise BagError(self.paths[-1] if self.paths else self.base, self.failed)
        if env is None:
            try:
                env = decode_envelope(frames)
            except DecodeError as exc:
                raise BagError(self.paths[-1], f"refusing a malformed message: {exc}") from None
        if log_ns is None:
            log_ns = time.time_ns()
        log_ns = max(0, log_ns)
        if self._file_first_log is None:
            self._file_first_log = log_ns
        elif (self.split_ns and log_ns - self._file_first_log >= self.split_ns) or self._size_due():
            self._rotate()
            self._file_first_log = log_ns
        topic = env.topic
        pub = max(0, env.publish_ns)
        if env.latched:
            self._latched[topic] = ([bytes(f) for f in frames], log_ns, pub, env.seq)
        try:
            self._add(topic, frames, env, log_ns, pub, env.seq)
        except OSError as exc:
            raise self._failure(exc) from None

    def _size_due(self) -> bool:
        if not self.split_bytes:
            return False
        self._since_size_check += 1
        if self._since_size_check < 64:
            return False
        self._since_size_check = 0
        return self._file.tell() >= self.split_bytes

    def write(self, topic: str, msg: Message, *, seq: int, capture_ns: int, publish_ns: int | None = None,
              log_ns: int | None = None, sender: str = "", latched: bool | None = None) -> None:
        """Encode and store a message (converters). Stamps default to ``capture_ns``."""
        publish_ns = capture_ns if publish_ns is None else publish_ns
        latched = msg.latched_by_default if latched is None else latched
        frames = encode(topic, msg, seq, capture_ns, sender, publish_ns, latched)
        self.write_frames(frames, capture_ns if log_ns is None else log_ns)

    def set_losses(self, losses: Mapping[str, int]) -> None:
        """Messages lost per topic so far (written at the next flush and at close)."""
        self.losses = {k: int(v) for k, v in losses.items() if v}

    def _write_losses(self, force: bool = False) -> None:
        if self.losses != self._losses_written or (force and self.losses):
            self._w.add_metadata(META_LOSSES, {k: str(v) for k, v in sorted(self.losses.items())})
            self._losses_written = dict(self.losses)

    def flush(self) -> None:
        """Close the current chunk and hand everything to the OS (survives a SIGKILL)."""
        if self._w is not None:
            try:
                self._w.flush()
                self._write_losses()
                self._file.flush()
            except OSError as exc:
                raise self._failure(exc) from None
            self._safe_in_file = self._in_file

    def close(self) -> list[Path]:
        """Finish every file (summary, indexes, footer). Returns the files written; BagError (one
        line, the files kept named) when the disk refused, now or before."""
        self._finish_file()
        if self.failed:
            raise BagError(self.paths[-1] if self.paths else self.base, self.failed)
        return list(self.paths)

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _free_path(path: Path, on_exists: str) -> Path:
    """``path``, or (on_exists="rename") the first free ``<stem>_<n><suffix>``; "error" refuses."""
    if on_exists == "overwrite" or not path.exists():
        return path
    if on_exists == "error":
        raise BagError(path, "already exists (choose another name or --force to overwrite)")
    n = 1
    while True:
        cand = path.with_name(f"{path.stem}_{n}{path.suffix}")
        if not cand.exists():
            return cand
        n += 1
