"""Protobuf wire bytes for many fixed-layout records at once (numpy; no protobuf runtime).

A record whose fields are all doubles (or nested messages of doubles) has the same length
whatever the values, once every field is written (proto3 readers accept explicit zeros). Its
bytes are then a template with the doubles' 8-byte slots at fixed offsets: N records are the
template tiled N times with one fancy-index assignment of the values, so a frame of 60 spheres
costs a few numpy calls instead of 300 Python objects. Layouts are lists of
``(field_number, "d" | "u" | nested_layout)``: "d" a double, "u" a one-byte varint (enum/bool < 128).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Sequence, Union

import numpy as np

Layout = Sequence[tuple[int, Union[str, "Layout"]]]

WIRE_VARINT, WIRE_FIXED64, WIRE_LEN = 0, 1, 2


_SMALL = [bytes((i,)) for i in range(128)]


def varint(n: int) -> bytes:
    """Protobuf base-128 varint of a non-negative int."""
    if n < 128:
        return _SMALL[n]
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


@lru_cache(maxsize=256)
def key(field: int, wire: int) -> bytes:
    return varint((field << 3) | wire)


def length_delimited(field: int, payload: bytes) -> bytes:
    """Field ``field`` holding ``payload`` (a nested message, string or bytes)."""
    return key(field, WIRE_LEN) + varint(len(payload)) + payload


def _build(layout: Layout, out: bytearray, doubles: list[int], bytes_: list[int]) -> None:
    for field, kind in layout:
        if kind == "d":
            out += key(field, WIRE_FIXED64)
            doubles.append(len(out))
            out += b"\0" * 8
        elif kind == "u":
            out += key(field, WIRE_VARINT)
            bytes_.append(len(out))
            out += b"\0"
        else:
            inner = bytearray()
            d_in: list[int] = []
            b_in: list[int] = []
            _build(kind, inner, d_in, b_in)
            out += key(field, WIRE_LEN) + varint(len(inner))
            base = len(out)
            doubles.extend(base + o for o in d_in)
            bytes_.extend(base + o for o in b_in)
            out += inner


class FixedRecord:
    """N records of one layout as bytes; optionally each wrapped as repeated field ``field``.

    ``encode(doubles float[N,D], small uint8[N,U] | None) -> bytes``: doubles in layout order
    (depth first), small varints likewise.
    """

    def __init__(self, layout: Layout, field: int | None = None) -> None:
        body = bytearray()
        doubles: list[int] = []
        small: list[int] = []
        _build(layout, body, doubles, small)
        prefix = b"" if field is None else key(field, WIRE_LEN) + varint(len(body))
        self.template = np.frombuffer(prefix + bytes(body), np.uint8)
        shift = len(prefix)
        self.n_doubles = len(doubles)
        self.n_small = len(small)
        # byte index of every double's 8 bytes, in order: [D*8]
        self._dbl = (np.asarray(doubles, np.intp)[:, None] + shift + np.arange(8)).ravel()
        self._small = np.asarray(small, np.intp) + shift
        self.size = len(self.template)

    def encode(self, doubles: np.ndarray, small: np.ndarray | None = None) -> bytes:
        doubles = np.ascontiguousarray(doubles, dtype="<f8")
        n = doubles.shape[0]
        if doubles.shape != (n, self.n_doubles):
            raise ValueError(f"expected float[N,{self.n_doubles}], got {doubles.shape}")
        out = np.empty((n, self.size), np.uint8)
        out[:] = self.template
        out[:, self._dbl] = doubles.view(np.uint8).reshape(n, self.n_doubles * 8)
        if self.n_small:
            out[:, self._small] = np.asarray(small, np.uint8).reshape(n, self.n_small)
        return out.tobytes()
