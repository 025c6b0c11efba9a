"""JSON from outside (commands, browser and Foxglove messages) parsed only within size and depth bounds.

Python's parser recurses once per ``[`` or ``{``: 50 000 of them raise RecursionError, which is
no ValueError and took nodes down. The text's length and its nesting depth are checked before
parsing, so hostile text is refused with one line (ValueError) and costs at most one linear scan.
The depth scan is vectorised: the quotes that open or close strings are found (those not escaped
by an odd run of backslashes), brackets inside strings are dropped, and the running sum of
opening minus closing brackets gives the depth at every byte.
"""
from __future__ import annotations

import json
from typing import Any

import numpy as np

MAX_BYTES = 1 << 20   # 1 MiB: a command or a browser message is a few hundred bytes
MAX_DEPTH = 32        # our own documents nest 4 deep at most

_DELTA = np.zeros(256, np.int8)   # +1 opens, -1 closes an array or object
_DELTA[[ord("["), ord("{")]] = 1
_DELTA[[ord("]"), ord("}")]] = -1


def json_depth(data: bytes) -> int:
    """Deepest nesting of arrays/objects in JSON text ``data`` (unbalanced text: its deepest point)."""
    if data.count(b"[") + data.count(b"{") == 0:
        return 0
    code = np.frombuffer(data, np.uint8)
    quote = code == 34
    if b"\\" in data:   # a quote ends or starts a string unless an odd run of backslashes precedes it
        idx = np.arange(code.size, dtype=np.int32)
        last_plain = np.maximum.accumulate(np.where(code == 92, np.int32(-1), idx))
        run = np.zeros(code.size, np.int32)
        run[1:] = idx[:-1] - last_plain[:-1]
        quote &= run % 2 == 0
    outside = (np.cumsum(quote, dtype=np.int32) & 1) == 0   # brackets inside strings do not nest
    return max(0, int(np.cumsum(_DELTA[code] * outside, dtype=np.int32).max()))


def loads_bounded(text: str | bytes | bytearray | memoryview, max_bytes: int = MAX_BYTES,
                  max_depth: int = MAX_DEPTH) -> Any:
    """``json.loads(text)``, refused with ValueError (one line) when longer than ``max_bytes`` or
    nested deeper than ``max_depth`` -- checked before the parser runs."""
    data = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else bytes(text)
    if len(data) > max_bytes:
        raise ValueError(f"JSON of {len(data)} bytes is over the limit of {max_bytes}")
    # fewer brackets than the limit cannot nest deeper: the common case costs two byte counts
    if data.count(b"[") + data.count(b"{") > max_depth:
        depth = json_depth(data)
        if depth > max_depth:
            raise ValueError(f"JSON nested {depth} deep is over the limit of {max_depth}")
    return json.loads(data)
