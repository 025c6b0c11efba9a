"""Encoding messages to ZeroMQ multipart frames and back. No pickle: any language can read it.

Frames of one message::

    0  topic            UTF-8 followed by one NUL byte (so that ZeroMQ's prefix matching of
                        'markers' never delivers 'markers_raw')
    1  header           struct HEADER (little-endian) followed by the type name and the
                        sending node's name, both UTF-8
    2  fields           little-endian binary, in declaration order: each numeric scalar
                        (int: i64, float: f64, bool: u8), then each array's dimensions (u32
                        each, as many as the field's declared rank); then, only for types
                        with text fields, a UTF-8 JSON object of the str and string-list
                        fields. (Binary because this frame is parsed on every message: JSON
                        cost more than the rest of decoding on a cold cache.)
    3+ array payloads   raw C-order little-endian buffers, one frame per array field,
                        in declaration order

`field_layout(cls)` gives the struct format of frame 2 for a type; the JSON Schema of a type
(``Message.json_schema()``) lists the fields in the same order.

HEADER = magic b"MG", codec version (u8), flags (u8), schema version (u16), type-name length
(u16), node-name length (u16), sequence number (u64), capture stamp ns (i64), publish stamp ns
(i64), stream id (u32). The stream id is drawn at random when a process starts (`STREAM_ID`): a
restarted sender is a new stream whatever its numbers say (`messages.sequence`). Codec version 1
headers (bags recorded before; no stream id, read as stream 0) are still decoded.
"""
from __future__ import annotations

import json
import math
import operator
import os
import struct
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .bounded_json import loads_bounded
from .clock_sync import wall_ns
from .registry import UnknownTypeError, lookup
from .schema import SCALAR_TYPES as SCALAR_PY
from .schema import Message, MessageError

MAGIC = b"MG"
CODEC_VERSION = 2
_HEADER_FIELDS = (("magic", "2s"), ("codec", "B"), ("flags", "B"), ("schema", "H"), ("type_len", "H"),
                  ("sender_len", "H"), ("seq", "Q"), ("capture_ns", "q"), ("publish_ns", "q"), ("stream", "I"))
HEADER = struct.Struct("<" + "".join(f for _, f in _HEADER_FIELDS))
#: the header of codec version 1 (no stream id): read, never written
HEADER_V1 = struct.Struct("<" + "".join(f for _, f in _HEADER_FIELDS[:-1]))
#: byte offset of each header field, for in-place reads and writes (bag play restamps headers);
#: the same in both versions (the stream id was appended)
HEADER_AT = {name: struct.calcsize("<" + "".join(f for _, f in _HEADER_FIELDS[:i]))
             for i, (name, _) in enumerate(_HEADER_FIELDS)}
#: fixed header bytes (before the names) by codec version
HEADER_SIZE = {1: HEADER_V1.size, CODEC_VERSION: HEADER.size}
_U64 = struct.Struct("<Q")
_I64 = struct.Struct("<q")
_LENS = struct.Struct("<HH")
_U32 = struct.Struct("<I")


def _new_stream_id() -> int:
    """A random non-zero u32 (0 is what a version 1 header reads as)."""
    return int.from_bytes(os.urandom(4), "little") or 1


#: this process's stream id, in every header it encodes (a forked child draws its own)
STREAM_ID = _new_stream_id()


def _after_fork() -> None:
    global STREAM_ID
    STREAM_ID = _new_stream_id()


os.register_at_fork(after_in_child=_after_fork)


def header_seq(head: bytes | bytearray | memoryview) -> int:
    """The sequence number of a header frame."""
    return _U64.unpack_from(head, HEADER_AT["seq"])[0]


def header_capture_ns(head: bytes | bytearray | memoryview) -> int:
    """The capture stamp (ns) of a header frame."""
    return _I64.unpack_from(head, HEADER_AT["capture_ns"])[0]


def header_sender(head: bytes | bytearray | memoryview) -> bytes:
    """The sender's name (UTF-8 bytes) of a header frame."""
    tlen, slen = _LENS.unpack_from(head, HEADER_AT["type_len"])
    at = HEADER_SIZE.get(head[HEADER_AT["codec"]], HEADER.size) + tlen
    return bytes(head[at:at + slen])


def header_stream(head: bytes | bytearray | memoryview) -> int:
    """The stream id of a header frame (0 for a version 1 header)."""
    return _U32.unpack_from(head, HEADER_AT["stream"])[0] if head[HEADER_AT["codec"]] == CODEC_VERSION else 0


def set_header_seq(head: bytearray, seq: int) -> None:
    _U64.pack_into(head, HEADER_AT["seq"], seq)


def set_header_publish_ns(head: bytearray, ns: int) -> None:
    _I64.pack_into(head, HEADER_AT["publish_ns"], ns)


def header_latched(head: bytes | bytearray | memoryview) -> bool:
    return bool(head[HEADER_AT["flags"]] & FLAG_LATCHED)
FLAG_LATCHED = 0x01


class DecodeError(ValueError):
    """A frame set that is not a valid mocapgraph message (counted and skipped by receivers)."""


@dataclass(slots=True)
class Envelope:
    """Everything a receiver knows about one message besides its payload."""

    topic: str
    type_name: str
    schema_version: int
    seq: int
    capture_ns: int
    publish_ns: int
    sender: str
    latched: bool
    #: the sender process's stream id (`STREAM_ID`; 0: a version 1 header)
    stream: int = 0


def topic_frame(topic: str) -> bytes:
    """The first frame of a message on ``topic``, also the exact ZeroMQ subscription prefix."""
    key = _TOPIC_FRAMES.get(topic)
    if key is None:
        key = topic.encode() + b"\0"
        if len(_TOPIC_FRAMES) < 4096:   # a graph's topics; bounded against garbage
            _TOPIC_FRAMES[topic] = key
    return key


_TOPIC_FRAMES: dict[str, bytes] = {}


class _Plan:
    """Per-type encoding plan: the struct of frame 2 and the field order."""

    def __init__(self, info) -> None:
        self.numeric = [sc for sc in info.scalars if sc.kind != "str"]
        self.text = [sc for sc in info.scalars if sc.kind == "str"] + list(info.strings)
        self.arrays = [(a, np.dtype(a.dtype)) for a in info.arrays]
        self.ranks = [len(a.shape) for a in info.arrays]
        self.struct = struct.Struct(info.field_block())
        self.py = [SCALAR_PY[sc.kind] for sc in self.numeric]
        self.array_names = [a.name for a in info.arrays]
        self.string_names = [f.name for f in info.strings]
        # a message's arrays and numeric scalars out of its __dict__, as tuples, in one C call each
        self.get_arrays = _getter(self.array_names)
        self.get_numeric = _getter([sc.name for sc in self.numeric])
        self.get_text = _getter([f.name for f in self.text])
        # per-stream caches (speed only; the bytes are the same): the text block of str-only text
        # fields by their values, parsed text blocks by their bytes, and the array dims last
        # validated with their (name, dtype, shape, nbytes): a stream's frames keep their shapes
        self.text_str_only = all(getattr(f, "kind", None) == "str" for f in self.text)
        self.text_out: dict[tuple, bytes] = {}
        self.names_out: dict[str, tuple[int, int, bytes]] = {}   # by sender: header name lengths and bytes
        self.text_in: dict[bytes, dict] = {}
        self.last_dims: tuple | None = None
        self.last_layout: list = []
        self.local_shapes: list | None = None   # the array shapes `local_copy` checked last


def _getter(names: list[str]):
    """``d -> tuple(d[n] for n in names)`` (operator.itemgetter, which returns a bare value for one name)."""
    if len(names) >= 2:
        return operator.itemgetter(*names)
    if names:
        one = operator.itemgetter(names[0])
        return lambda d: (one(d),)
    return lambda d: ()


TEXT_BLOCK_DEPTH = 8   # a text block is an object of strings and lists of strings: 3 deep
_TEXT_CACHE = 256   # distinct text blocks remembered per type (a few names per graph; bounded against garbage)
_PLAN_CACHE: dict[str, _Plan] = {}


def _plan(info) -> _Plan:
    plan = _PLAN_CACHE.get(info.name)
    if plan is None:
        plan = _PLAN_CACHE[info.name] = _Plan(info)
    return plan


def field_layout(cls: type[Message]) -> str:
    """The struct format string of frame 2 for ``cls`` (numeric scalars, then array dims)."""
    return cls._info.field_block()


def encode(topic: str, msg: Message, seq: int, capture_ns: int, sender: str = "", publish_ns: int | None = None,
           latched: bool = False) -> list[bytes | memoryview]:
    """The multipart frames of ``msg`` on ``topic``. ``publish_ns`` defaults to now."""
    head, arrays = encode_head(topic, msg, seq, capture_ns, sender, publish_ns, latched)
    return head + array_frames(arrays)


def encode_head(
    topic: str,
    msg: Message,
    seq: int,
    capture_ns: int,
    sender: str = "",
    publish_ns: int | None = None,
    latched: bool = False,
) -> tuple[list[bytes], tuple[np.ndarray, ...]]:
    """:func:`encode` in two steps: the first three frames (topic, header, field block; stamped
    last) and the arrays whose frames :func:`array_frames` makes (an in-process subscriber gets the
    message before its socket frames are assembled)."""
    info = msg._info
    plan = _plan(info)
    names = plan.names_out.get(sender)
    if names is None:   # (type name, sender name) bytes and lengths: once per sender
        tname, sname = info.name.encode(), sender.encode()
        names = (len(tname), len(sname), tname + sname)
        if len(plan.names_out) < _TEXT_CACHE:
            plan.names_out[sender] = names
    d = msg.__dict__
    arrays = plan.get_arrays(d)
    values = [*plan.get_numeric(d)]
    for arr in arrays:
        values += arr.shape
    block = plan.struct.pack(*values)
    if plan.text:
        if plan.text_str_only:   # json.dumps costs ~10 us: once per distinct name
            key = plan.get_text(d)
            text = plan.text_out.get(key)
            if text is None:
                text = json.dumps({f.name: d[f.name] for f in plan.text}, separators=(",", ":")).encode()
                if len(plan.text_out) < _TEXT_CACHE:
                    plan.text_out[key] = text
            block += text
        else:
            block += json.dumps({f.name: d[f.name] for f in plan.text}, separators=(",", ":")).encode()
    header = HEADER.pack(
        MAGIC,
        CODEC_VERSION,
        FLAG_LATCHED if latched else 0,
        info.version,
        names[0],
        names[1],
        seq,
        capture_ns,
        wall_ns() if publish_ns is None else publish_ns,  # stamped last: encoding is not latency
        STREAM_ID,
    )
    return [topic_frame(topic), header + names[2], block], arrays


def array_frames(arrays: tuple[np.ndarray, ...]) -> list[memoryview | bytes]:
    """The payload frames of a message's arrays (:func:`encode_head`): views of their bytes."""
    # The field setters keep arrays contiguous with the declared dtype; native order on every
    # platform we support is little-endian.
    return [memoryview(arr).cast("B") if arr.size else b"" for arr in arrays]


_NAMES: dict[tuple[int, bytes], tuple[str, str]] = {}


def decode_envelope(frames: Sequence[bytes | memoryview]) -> Envelope:
    """Read topic and header only (cheap: recorders and statistics need no payload)."""
    if len(frames) < 3:
        raise DecodeError(f"{len(frames)} frame(s), a message has at least 3")
    head = bytes(frames[1])
    if len(head) < HEADER.size:
        return _decode_v1(frames, head)
    magic, codec, flags, version, tlen, slen, seq, cap, pub, stream = HEADER.unpack_from(head)
    if magic != MAGIC or codec != CODEC_VERSION:
        return _decode_v1(frames, head)
    return _envelope(frames, head, HEADER.size, tlen, slen, version, seq, cap, pub, flags, stream)


def _decode_v1(frames: Sequence[bytes | memoryview], head: bytes) -> Envelope:
    """A version 1 header (no stream id: stream 0), or the reason the header is not one we read."""
    if len(head) < HEADER_V1.size:
        raise DecodeError(f"header of {len(head)} bytes is truncated")
    magic, codec, flags, version, tlen, slen, seq, cap, pub = HEADER_V1.unpack_from(head)
    if magic != MAGIC:
        raise DecodeError("bad magic: not a mocapgraph message")
    if codec != 1:
        raise DecodeError(f"codec version {codec} is not supported (this is {CODEC_VERSION})")
    return _envelope(frames, head, HEADER_V1.size, tlen, slen, version, seq, cap, pub, flags, 0)


def _envelope(frames: Sequence[bytes | memoryview], head: bytes, size: int, tlen: int, slen: int, version: int,
              seq: int, cap: int, pub: int, flags: int, stream: int) -> Envelope:
    """The envelope of a header whose fixed part (``size`` bytes) is read: names and topic checked."""
    if len(head) != size + tlen + slen:
        raise DecodeError("header length does not match its name lengths")
    key = (tlen, head[size:])
    names = _NAMES.get(key)
    if names is None:
        try:
            names = (head[size : size + tlen].decode(), head[size + tlen :].decode())
        except UnicodeDecodeError as exc:
            raise DecodeError(f"names are not UTF-8 ({exc.reason})") from None
        if len(_NAMES) < 4096:  # a few (type, sender) pairs per graph; bounded against garbage
            _NAMES[key] = names
    tname, sname = names
    try:
        t = frames[0] if isinstance(frames[0], bytes) else bytes(frames[0])
        topic = (t[:-1] if t.endswith(b"\0") else t).decode()
    except UnicodeDecodeError as exc:
        raise DecodeError(f"names are not UTF-8 ({exc.reason})") from None
    return Envelope(topic, tname, version, seq, cap, pub, sname, bool(flags & FLAG_LATCHED), stream)


def local_envelope(topic: str, type_name: str, sender: str, head: bytes) -> Envelope:
    """The envelope of a header this process has just encoded: the names are known, nothing to check."""
    _, _, flags, version, _, _, seq, cap, pub, stream = HEADER.unpack_from(head)
    return Envelope(topic, type_name, version, seq, cap, pub, sender, bool(flags & FLAG_LATCHED), stream)


def decode(frames: Sequence[bytes | memoryview]) -> tuple[Envelope, Message]:
    """Envelope and message of a frame set; raises DecodeError on anything malformed."""
    env = decode_envelope(frames)
    try:
        cls = lookup(env.type_name)
    except UnknownTypeError as exc:
        raise DecodeError(str(exc)) from None
    return env, decode_payload(cls, env, frames)


def decode_payload(cls: type[Message], env: Envelope, frames: Sequence[bytes | memoryview]) -> Message:
    """The message body, checked against the declared schema of ``cls``."""
    info = cls._info
    if env.schema_version != info.version:
        raise DecodeError(
            f"{info.name} schema version {env.schema_version} differs from this build's {info.version}"
        )
    plan = _plan(info)
    if len(frames) != 3 + len(plan.arrays):
        raise DecodeError(f"{info.name} wants {3 + len(plan.arrays)} frames, got {len(frames)}")
    block = frames[2]
    if not isinstance(block, bytes):
        block = bytes(block)
    st = plan.struct
    if len(block) < st.size:
        raise DecodeError(f"{info.name} field block of {len(block)} bytes is truncated (wants {st.size})")
    values = st.unpack_from(block)
    msg = cls.__new__(cls)
    d = msg.__dict__
    n = len(plan.numeric)
    for sc, py, v in zip(plan.numeric, plan.py, values):
        d[sc.name] = v if type(v) is py else py(v)
    if plan.text:
        try:
            raw = block[st.size:]
            text = plan.text_in.get(raw)
            if text is None:
                # bounded before parsing: a forged block of 50 000 '[' is a DecodeError, not a RecursionError
                text = loads_bounded(raw, len(raw) + 1, TEXT_BLOCK_DEPTH)
                if not isinstance(text, dict):
                    raise TypeError("not an object")
                if len(plan.text_in) < _TEXT_CACHE and len(raw) < 1024:
                    plan.text_in[raw] = text   # read only below: coerce copies lists
            for f in plan.text:
                d[f.name] = f.coerce(text[f.name]) if f.name in text else (f.default if hasattr(f, "default") else [])
        except (ValueError, TypeError, KeyError) as exc:
            raise DecodeError(f"{info.name} text fields are not valid JSON ({exc})") from None
        except MessageError as exc:
            raise DecodeError(f"{info.name}: {exc}") from None
    elif len(block) != st.size:
        raise DecodeError(f"{info.name} field block has {len(block) - st.size} bytes too many")
    dims = values[n:]
    if dims == plan.last_dims:   # the shapes validated last time: only the byte counts to check
        for (name, dtype, shape, nbytes), buf in zip(plan.last_layout, frames[3:]):
            if (len(buf) if type(buf) is bytes else memoryview(buf).nbytes) != nbytes:
                break   # the full check below says what is wrong
            d[name] = np.ndarray(shape, dtype, buf)
        else:
            return msg
    symbols: dict[str, int] = {}
    i = n
    layout = []
    for (spec, dtype), rank, buf in zip(plan.arrays, plan.ranks, frames[3:]):
        shape = values[i:i + rank]
        i += rank
        d[spec.name] = _decode_array(info.name, spec, dtype, shape, buf, symbols)
        layout.append((spec.name, dtype, shape, math.prod(shape) * dtype.itemsize))
    plan.last_dims, plan.last_layout = dims, layout
    return msg


def local_copy(msg: Message) -> Message:
    """``msg`` as a subscriber in the publisher's own process receives it, without the bytes:
    read-only copies of its arrays (as decoded ones are; the publisher may reuse its own), fresh
    string lists, the shapes checked as `decode_payload` checks them (DecodeError otherwise)."""
    info = msg._info
    plan = _plan(info)
    d = msg.__dict__
    arrays = plan.get_arrays(d)
    shapes = [arr.shape for arr in arrays]
    if shapes != plan.local_shapes:   # a stream keeps its shapes: checked once per change
        symbols: dict[str, int] = {}
        for (spec, _), shape in zip(plan.arrays, shapes):
            _check_shape(info.name, spec, shape, symbols)
        plan.local_shapes = shapes
    cls = type(msg)
    out = cls.__new__(cls)
    od = out.__dict__
    od.update(d)
    for name, arr in zip(plan.array_names, arrays):
        c = arr.copy()
        c.setflags(write=False)   # (setflags: no flags object built, as the attribute would)
        od[name] = c
    for name in plan.string_names:
        od[name] = list(od[name])
    return out


def _check_shape(tname: str, spec, shape: tuple, symbols: dict[str, int]) -> None:
    """Sizes against the declared shape of ``spec``; symbols (N, J) must agree across fields."""
    for size, want in zip(shape, spec.shape):
        if type(want) is int:
            if size != want:
                raise DecodeError(f"{tname}.{spec.name}: shape {list(shape)} is not {spec.shape_text()}")
        elif symbols.setdefault(want, size) != size:
            raise DecodeError(
                f"{tname}.{spec.name}: {want}={size} disagrees with {want}={symbols[want]} elsewhere"
            )


def _decode_array(tname: str, spec, dtype: np.dtype, shape: tuple, buf, symbols: dict[str, int]) -> np.ndarray:
    _check_shape(tname, spec, shape, symbols)
    count = math.prod(shape)
    nbytes = len(buf) if isinstance(buf, bytes) else memoryview(buf).nbytes
    if nbytes != count * dtype.itemsize:
        raise DecodeError(
            f"{tname}.{spec.name}: {nbytes} bytes for shape {list(shape)} of {dtype} "
            f"(wants {count * dtype.itemsize})"
        )
    return np.ndarray(shape, dtype, buf)  # one C call: a read-only view of the frame
