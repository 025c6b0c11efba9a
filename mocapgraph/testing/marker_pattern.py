"""A signal generator for checking a graph's wiring: markers on circles at a fixed rate."""
from __future__ import annotations

import time

import numpy as np

from ..bus import Input, Node, Output, Param
from ..messages import MarkerFrame, MarkerLayout


def pattern_positions(frame: int, n_markers: int, rate_hz: float) -> np.ndarray:
    """Marker i on a circle of radius 0.1 m + 0.01 m * i at height 1 m, turning at 0.5 Hz; m, world."""
    t = frame / rate_hz
    i = np.arange(n_markers)
    angle = 2 * np.pi * 0.5 * t + i * (2 * np.pi / max(n_markers, 1))
    r = 0.1 + 0.01 * i
    return np.stack([r * np.cos(angle), r * np.sin(angle), np.ones(n_markers)], axis=1)


class MarkerTestPattern(Node):
    """Publishes a deterministic marker pattern (and its latched layout) at a fixed rate."""

    summary = "deterministic marker pattern for checking wiring, rates and latency"
    markers = Output("markers", MarkerFrame, "marker frames, m, world")
    layout = Output("marker_layout", MarkerLayout, "latched layout of the pattern")
    rate_hz = Param(100.0, "frames per second, Hz", minimum=0.1)
    n_markers = Param(8, "markers per frame", minimum=1)
    count = Param(0, "frames to send before stopping; 0 sends forever", minimum=0)
    missing_every = Param(0, "mark marker 0 missing on every Nth frame (0: never)", minimum=0)

    def on_start(self) -> None:
        n = self.n_markers
        self.layout.publish(MarkerLayout(
            name="test_pattern", labels=[f"P{i}" for i in range(n)], limb_names=[],
            marker_limb=np.full(n, -1), units_note="generated in metres, world frame", source="test pattern"))
        self.frame = 0
        self.add_timer(1.0 / self.rate_hz, self.tick, first_delay_s=0.0)

    def tick(self) -> None:
        n = self.n_markers
        pos = pattern_positions(self.frame, n, self.rate_hz)
        valid = np.ones(n, bool)
        if self.missing_every and self.frame % self.missing_every == 0:
            pos[0] = np.nan
            valid[0] = False
        self.markers.publish(MarkerFrame(frame_number=self.frame, rate_hz=self.rate_hz, positions=pos,
                                         valid=valid, residual=np.zeros(n, np.float32)),
                             capture_ns=time.time_ns())
        self.frame += 1
        if self.count and self.frame >= self.count:
            self.request_stop()
