"""Helpers shared by the bag tests: synthetic bags with known content."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import MarkerFrame, MarkerLayout, encode


def frame(i: int, n: int = 4) -> MarkerFrame:
    pos = np.arange(n * 3, dtype=float).reshape(n, 3) + i
    return MarkerFrame(frame_number=i, rate_hz=100.0, positions=pos, valid=np.ones(n, bool),
                       residual=np.zeros(n, np.float32))


def layout(n: int = 4) -> MarkerLayout:
    return MarkerLayout(name="t", labels=[f"M{k}" for k in range(n)], limb_names=[],
                        marker_limb=np.full(n, -1), units_note="", unplaced=[], source="test")


def write_bag(path: Path, frames: int = 50, period_ns: int = 10_000_000, t0: int = 1_000_000_000,
              seq0: int = 1, sender: str = "src", **kw) -> Path:
    """A bag with a latched layout then ``frames`` MarkerFrames every ``period_ns`` (publish = log = capture)."""
    with BagWriter(path, **kw) as w:
        w.write_frames(encode("marker_layout", layout(), 1, t0, sender, t0, latched=True), t0)
        for i in range(frames):
            t = t0 + i * period_ns
            w.write_frames(encode("markers", frame(i), seq0 + i, t, sender, t), t)
    return path
