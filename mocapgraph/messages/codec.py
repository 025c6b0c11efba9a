"""Encoding messages to ZeroMQ multipart frames and back. No pickle: any language can read it.

Frames of one message::

    0  topic            UTF-8 followed by one NUL byte (so that ZeroMQ's prefix matching of
                        'markers' never delivers 'markers_raw')
    1  header           struct HEADER (little-endian) followed by the type name and the
                        sending node's name, both UTF-8
    2  fields           JSON object: {"f": {scalar and string-list fields}, "s": [array shapes]}
    3+ array payloads   raw C-order little-endian buffers, one frame per array field,
                        in declaration order

HEADER = magic b"MG", codec version (u8), flags (u8), schema version (u16), type-name length
(u16), node-name length (u16), sequence number (u64), capture stamp ns (i64), publish stamp ns
(i64).
"""
from __future__ import annotations

import json
import math
import struct
import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .registry import UnknownTypeError, lookup
from .schema import SCALAR_TYPES as SCALAR_PY
from .schema import Message, MessageError

MAGIC = b"MG"
CODEC_VERSION = 1
HEADER = struct.Struct("<2sBBHHHQqq")
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


def topic_frame(topic: str) -> bytes:
    """The first frame of a message on ``topic``, also the exact ZeroMQ subscription prefix."""
    return topic.encode() + b"\0"


def encode(
    topic: str,
    msg: Message,
    seq: int,
    capture_ns: int,
    sender: str = "",
    publish_ns: int | None = None,
    latched: bool = False,
) -> list[bytes | memoryview]:
    """The multipart frames of ``msg`` on ``topic``. ``publish_ns`` defaults to now."""
    info = msg._info
    tname = info.name.encode()
    sname = sender.encode()
    d = msg.__dict__
    fields = {s.name: d[s.name] for s in info.scalars}
    for s in info.strings:
        fields[s.name] = d[s.name]
    arrays = [d[a.name] for a in info.arrays]
    meta = json.dumps({"f": fields, "s": [a.shape for a in arrays]}, separators=(",", ":"))
    header = HEADER.pack(
        MAGIC,
        CODEC_VERSION,
        FLAG_LATCHED if latched else 0,
        info.version,
        len(tname),
        len(sname),
        seq,
        capture_ns,
        time.time_ns() if publish_ns is None else publish_ns,  # stamped last: encoding is not latency
    )
    frames: list[bytes | memoryview] = [topic_frame(topic), header + tname + sname, meta.encode()]
    for arr in arrays:
        # The field setters keep arrays contiguous with the declared dtype; native order on
        # every platform we support is little-endian.
        frames.append(memoryview(arr).cast("B") if arr.size else b"")
    return frames


def decode_envelope(frames: Sequence[bytes | memoryview]) -> Envelope:
    """Read topic and header only (cheap: recorders and statistics need no payload)."""
    if len(frames) < 3:
        raise DecodeError(f"{len(frames)} frame(s), a message has at least 3")
    head = bytes(frames[1])
    if len(head) < HEADER.size:
        raise DecodeError(f"header of {len(head)} bytes is truncated")
    magic, codec, flags, version, tlen, slen, seq, cap, pub = HEADER.unpack_from(head)
    if magic != MAGIC:
        raise DecodeError("bad magic: not a mocapgraph message")
    if codec != CODEC_VERSION:
        raise DecodeError(f"codec version {codec} is not supported (this is {CODEC_VERSION})")
    if len(head) != HEADER.size + tlen + slen:
        raise DecodeError("header length does not match its name lengths")
    try:
        tname = head[HEADER.size : HEADER.size + tlen].decode()
        sname = head[HEADER.size + tlen :].decode()
        topic = bytes(frames[0]).rstrip(b"\0").decode()
    except UnicodeDecodeError as exc:
        raise DecodeError(f"names are not UTF-8 ({exc.reason})") from None
    return Envelope(topic, tname, version, seq, cap, pub, sname, bool(flags & FLAG_LATCHED))


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
    if len(frames) != 3 + len(info.arrays):
        raise DecodeError(f"{info.name} wants {3 + len(info.arrays)} frames, got {len(frames)}")
    block = frames[2]
    try:
        meta = json.loads(block if isinstance(block, bytes) else bytes(block))
        values = meta["f"]
        shapes = meta["s"]
    except (ValueError, KeyError, TypeError) as exc:
        raise DecodeError(f"{info.name} field block is not valid JSON ({exc})") from None
    if not isinstance(values, dict) or not isinstance(shapes, list) or len(shapes) != len(info.arrays):
        raise DecodeError(f"{info.name} field block has the wrong layout")
    msg = cls.__new__(cls)
    d = msg.__dict__
    try:
        for s, py in _scalar_plan(info):
            v = values.get(s.name, s.default)
            d[s.name] = v if type(v) is py else s.coerce(v)
        for s in info.strings:
            d[s.name] = s.coerce(values.get(s.name, []))
    except MessageError as exc:
        raise DecodeError(f"{info.name}: {exc}") from None
    symbols: dict[str, int] = {}
    for (spec, dtype), shape, buf in zip(_array_plan(info), shapes, frames[3:]):
        d[spec.name] = _decode_array(info.name, spec, dtype, shape, buf, symbols)
    return msg


_PLANS: dict[str, tuple[list, list]] = {}


def _scalar_plan(info) -> list:
    plan = _PLANS.get(info.name)
    if plan is None:
        plan = _PLANS[info.name] = (
            [(s, SCALAR_PY[s.kind]) for s in info.scalars],
            [(a, np.dtype(a.dtype)) for a in info.arrays],
        )
    return plan[0]


def _array_plan(info) -> list:
    return _PLANS[info.name][1] if info.name in _PLANS else (_scalar_plan(info), _PLANS[info.name][1])[1]


def _decode_array(tname: str, spec, dtype: np.dtype, shape, buf, symbols: dict[str, int]) -> np.ndarray:
    if type(shape) is not list or len(shape) != len(spec.shape):
        raise DecodeError(f"{tname}.{spec.name}: shape {shape} does not match {spec.shape_text()}")
    for size, want in zip(shape, spec.shape):
        if type(size) is not int or size < 0:
            raise DecodeError(f"{tname}.{spec.name}: bad shape {shape}")
        if type(want) is int:
            if size != want:
                raise DecodeError(f"{tname}.{spec.name}: shape {shape} is not {spec.shape_text()}")
        elif symbols.setdefault(want, size) != size:
            raise DecodeError(
                f"{tname}.{spec.name}: {want}={size} disagrees with {want}={symbols[want]} elsewhere"
            )
    count = math.prod(shape)
    nbytes = len(buf) if isinstance(buf, bytes) else memoryview(buf).nbytes
    if nbytes != count * dtype.itemsize:
        raise DecodeError(
            f"{tname}.{spec.name}: {nbytes} bytes for shape {shape} of {dtype} "
            f"(wants {count * dtype.itemsize})"
        )
    return np.frombuffer(buf, dtype=dtype).reshape(shape)
