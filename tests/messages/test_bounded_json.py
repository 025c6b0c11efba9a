"""The vectorised JSON depth scan against the parsed documents' own depth (an independent
reference: Python's parser on text shallow enough for it), and the bounds refusing in one line."""
from __future__ import annotations

import json
import random

import pytest

from mocapgraph.messages.bounded_json import json_depth, loads_bounded

TRICKY = ['[', ']', '{', '}', '"', '\\', '\\"', '\\\\', 'a', ' ', '\\u005b', ':', ',']


def _depth(x) -> int:
    if isinstance(x, list):
        return 1 + max((_depth(v) for v in x), default=0)
    if isinstance(x, dict):
        return 1 + max((_depth(v) for v in x.values()), default=0)
    return 0


def _random_doc(rng: random.Random, depth: int):
    kind = rng.random()
    if depth == 0 or kind < 0.3:
        return "".join(rng.choice(TRICKY) for _ in range(rng.randint(0, 6))) if kind < 0.2 else rng.random()
    if kind < 0.65:
        return [_random_doc(rng, depth - 1) for _ in range(rng.randint(0, 3))]
    return {"".join(rng.choice(TRICKY) for _ in range(rng.randint(0, 4))): _random_doc(rng, depth - 1)
            for _ in range(rng.randint(0, 3))}


def test_depth_scan_matches_the_parsed_depth_on_2000_random_documents():
    rng = random.Random(7)
    for _ in range(2000):
        doc = _random_doc(rng, rng.randint(0, 12))
        text = json.dumps(doc, ensure_ascii=rng.random() < 0.5)
        assert json_depth(text.encode()) == _depth(json.loads(text)), text


def test_bounds_refuse_before_parsing_in_one_line():
    with pytest.raises(ValueError, match="nested 100000 deep is over the limit of 8"):
        loads_bounded("[" * 100_000, max_depth=8)
    with pytest.raises(ValueError, match="bytes is over the limit of 1024"):
        loads_bounded(json.dumps("x" * 2000), max_bytes=1024)
    assert loads_bounded('{"a": ["[[[[[[[[[["]}', max_depth=2) == {"a": ["[[[[[[[[[["]}
    with pytest.raises(ValueError):
        loads_bounded('{"a": [[[1]]]}', max_depth=3)
