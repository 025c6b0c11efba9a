"""How one mocapgraph message is stored in one MCAP message record (encoding ``mocapgraph/frames-v1``).

A bus message is a list of ZeroMQ frames (see :mod:`mocapgraph.messages.codec`): topic, header,
field block, array payloads. A bag stores every frame but the topic (the MCAP channel carries
it), byte for byte, as::

    u32 n                     number of frames that follow (>= 2: header, field block, arrays...)
    u32 length[n]             byte length of each frame
    bytes frame[0] .. frame[n-1], concatenated, no padding

All integers little-endian. frame[0] is the codec header (magic b"MG", codec version, flags,
schema version, name lengths, sequence u64, capture stamp i64 ns, publish stamp i64 ns, then
type name and sender node name in UTF-8), frame[1] the JSON field block, frame[2:] the raw
little-endian C-order array buffers in the type's declaration order. The channel's schema record
(encoding ``jsonschema``) names each field's dtype and shape (``x-dtype``, ``x-shape``).
"""
from __future__ import annotations

import struct
from typing import Sequence

from .errors import BagError

MESSAGE_ENCODING = "mocapgraph/frames-v1"
_U32 = struct.Struct("<I")
_PACKERS: dict[int, struct.Struct] = {}


def pack_frames(frames: Sequence[bytes | memoryview]) -> bytes:
    """The MCAP message data of bus ``frames`` (topic frame first; it is left out)."""
    body = frames[1:]
    n = len(body)
    p = _PACKERS.get(n)
    if p is None:
        p = _PACKERS[n] = struct.Struct(f"<{n + 1}I")
    return p.pack(n, *[len(f) if isinstance(f, bytes) else memoryview(f).nbytes for f in body]) + b"".join(body)


def unpack_frames(data: bytes | memoryview, topic_frame: bytes = b"") -> list[bytes | memoryview]:
    """Bus frames from MCAP message data; ``topic_frame`` (topic + NUL) is put first when given.

    Frames are zero-copy views into ``data``. Raises BagError on a malformed record.
    """
    mv = memoryview(data)
    if len(mv) < 4:
        raise BagError(None, f"message record of {len(mv)} bytes is too short for {MESSAGE_ENCODING}")
    (n,) = _U32.unpack_from(mv, 0)
    head = 4 + 4 * n
    if n > 4096 or len(mv) < head:
        raise BagError(None, f"message record claims {n} frames, which do not fit its {len(mv)} bytes")
    lens = struct.unpack_from(f"<{n}I", mv, 4)
    if head + sum(lens) != len(mv):
        raise BagError(None, f"message record frame lengths add to {head + sum(lens)}, record holds {len(mv)}")
    out: list[bytes | memoryview] = [topic_frame] if topic_frame else []
    pos = head
    for ln in lens:
        out.append(mv[pos:pos + ln])
        pos += ln
    return out


def header_of(data: bytes | memoryview) -> memoryview:
    """The codec header frame of MCAP message data, without unpacking the rest."""
    mv = memoryview(data)
    (n,) = _U32.unpack_from(mv, 0)
    (ln,) = _U32.unpack_from(mv, 4)
    start = 4 + 4 * n
    return mv[start:start + ln]
