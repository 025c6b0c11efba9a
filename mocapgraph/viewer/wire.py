"""Binary bundles sent to the browser: several messages' latest values in one WebSocket frame.

Layout of one bundle (little-endian)::

    b"MGV1"  u32 json_len  JSON (UTF-8)  zero padding to a multiple of 8
    binary section: one block per array, each starting at a multiple of 8

The JSON is ``{"t_ms": server wall clock ms, "records": [record, ...]}`` and a record is
``{"topic", "type", "key", "sender", "seq", "capture_ms", "publish_ms", "latched",
"fields": {scalars and string lists}, "arrays": {name: [dtype, shape, offset]}}`` where
``offset`` counts bytes from the start of the binary section. Wire dtypes: ``f4`` (every float
field: positions in metres keep sub-micrometre precision, NaN survives), ``f8`` (int64
counters, exact below 2**53), ``u1`` (bool), ``i1``, ``i2``, ``i4``. Non-finite float scalars
become JSON null (JSON has no NaN).
"""
from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..messages import Array, Envelope, Message, Scalar

MAGIC = b"MGV1"
_WIRE = {"f": ("f4", np.float32), "b": ("u1", np.uint8)}
_INT_WIRE = {1: ("i1", np.int8), 2: ("i2", np.int16), 4: ("i4", np.int32)}
_FROM_WIRE = {"f4": np.float32, "f8": np.float64, "u1": np.uint8, "i1": np.int8, "i2": np.int16,
              "i4": np.int32}


class BundleError(ValueError):
    """A byte string that is not a viewer bundle."""


@dataclass
class EncodedRecord:
    """One message ready to be put into bundles: its JSON head and its array blocks."""

    head: dict[str, Any]
    names: list[str]
    blocks: list[tuple[str, list[int], bytes]]  # (wire dtype, shape, raw bytes)


def _wire_array(arr: np.ndarray) -> tuple[str, np.ndarray]:
    kind = arr.dtype.kind
    if kind in _WIRE:
        code, dt = _WIRE[kind]
        return code, arr.astype(dt, copy=False)
    if kind in "iu":
        if arr.dtype.itemsize in _INT_WIRE and kind == "i":
            code, dt = _INT_WIRE[arr.dtype.itemsize]
            return code, arr.astype(dt, copy=False)
        return "f8", arr.astype(np.float64)
    raise TypeError(f"array dtype {arr.dtype} has no wire form")


def _json_scalar(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def encode_record(topic: str, key: str, env: Envelope, msg: Message) -> EncodedRecord:
    """The wire form of ``msg`` received on ``topic`` (``key`` names its stream)."""
    fields: dict[str, Any] = {}
    names: list[str] = []
    blocks: list[tuple[str, list[int], bytes]] = []
    for name, spec in msg.fields().items():
        value = getattr(msg, name)
        if isinstance(spec, Array):
            code, arr = _wire_array(np.asarray(value))
            names.append(name)
            blocks.append((code, list(arr.shape), np.ascontiguousarray(arr).tobytes()))
        elif isinstance(spec, Scalar):
            fields[name] = _json_scalar(value)
        else:
            fields[name] = list(value)
    head = {"topic": topic, "type": env.type_name, "key": key, "sender": env.sender, "seq": env.seq,
            "capture_ms": env.capture_ns / 1e6, "publish_ms": env.publish_ns / 1e6, "latched": env.latched,
            "fields": fields}
    return EncodedRecord(head, names, blocks)


def build_bundle(records: list[EncodedRecord], t_ms: float) -> bytes:
    """One bundle of ``records`` (see the module docstring for the layout)."""
    heads = []
    parts: list[bytes] = []
    offset = 0
    for rec in records:
        arrays = {}
        for name, (code, shape, raw) in zip(rec.names, rec.blocks):
            arrays[name] = [code, shape, offset]
            pad = (-len(raw)) % 8
            parts.append(raw)
            if pad:
                parts.append(b"\0" * pad)
            offset += len(raw) + pad
        heads.append({**rec.head, "arrays": arrays})
    js = json.dumps({"t_ms": t_ms, "records": heads}, separators=(",", ":"), allow_nan=False).encode()
    pad = (-(8 + len(js))) % 8
    return b"".join([MAGIC, struct.pack("<I", len(js)), js, b"\0" * pad, *parts])


def decode_bundle(data: bytes) -> tuple[float, list[dict[str, Any]]]:
    """Python reader of a bundle (the page has its own in JS): (t_ms, records with numpy arrays)."""
    if len(data) < 8 or data[:4] != MAGIC:
        raise BundleError("not a viewer bundle (bad magic)")
    (n,) = struct.unpack_from("<I", data, 4)
    if 8 + n > len(data):
        raise BundleError("bundle JSON runs past the end")
    try:
        doc = json.loads(data[8:8 + n])
    except ValueError as exc:
        raise BundleError(f"bundle JSON is invalid ({exc})") from None
    base = 8 + n + ((-(8 + n)) % 8)
    out = []
    for rec in doc["records"]:
        arrays = {}
        for name, (code, shape, off) in rec["arrays"].items():
            dt = np.dtype(_FROM_WIRE[code])
            count = math.prod(shape)
            start = base + off
            if start + count * dt.itemsize > len(data):
                raise BundleError(f"array {name} of {rec['topic']} runs past the end")
            arrays[name] = np.frombuffer(data, dt, count, start).reshape(shape)
        out.append({**rec, "arrays": arrays})
    return doc["t_ms"], out
