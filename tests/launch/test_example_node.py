"""The README's example node runs as written: launched from its graph, it smooths what the pattern sends."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from graph_helpers import read_jsonl, wait_until

pytestmark = pytest.mark.slow  # a launched graph

GRAPH = Path(__file__).resolve().parents[2] / "graph_configs" / "examples" / "smooth_markers.yaml"


def _positions(rec: dict) -> np.ndarray:
    return np.array(rec["msg"]["positions"], dtype=float).reshape(-1, 3)


def test_example_node_smooths_the_pattern_as_its_docstring_says(launch_graph, tmp_path) -> None:
    log = tmp_path / "smooth.jsonl"
    g = launch_graph(GRAPH, f"log:={log}", "alpha:=0.25")
    wait_until(lambda: len(read_jsonl(log, "smoothed_markers")) >= 40, what="smoothed frames", graph=g)
    raw = {r["seq"]: r for r in read_jsonl(log, "markers")}
    smoothed = read_jsonl(log, "smoothed_markers")
    # the same recursion written out independently, from the raw frames the logger saw
    expected, last, checked, gaps = {}, None, 0, 0
    for seq in sorted(raw):
        r = raw[seq]
        new = np.where(np.array(r["msg"]["valid"])[:, None], _positions(r), np.nan)
        last = new if last is None else np.where(np.isnan(last), new, 0.25 * new + 0.75 * last)
        expected[r["msg"]["frame_number"]] = last.copy()
    for s in smoothed:
        frame = s["msg"]["frame_number"]
        if frame not in expected or frame - 1 not in expected:
            continue
        got = _positions(s)
        np.testing.assert_allclose(got, expected[frame], atol=1e-12, equal_nan=True)
        assert s["capture_ns"] == next(r["capture_ns"] for r in raw.values() if r["msg"]["frame_number"] == frame)
        gaps += int(np.isnan(got).any())
        checked += 1
    assert checked >= 30
    assert gaps > 0   # the pattern drops a marker every 7th frame: it must come out NaN, not 0,0,0
