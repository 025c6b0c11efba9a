"""An example node (the README's): every marker smoothed over time, NaN where it is not seen."""
from __future__ import annotations

import numpy as np

from mocapgraph.bus import Input, Node, Output, Param
from mocapgraph.messages import MarkerFrame


class SmoothMarkers(Node):
    """Exponential smoothing of each marker's position; a marker that is not seen starts afresh."""

    summary = "markers smoothed over time (exponential, per marker) -> MarkerFrame"
    markers = Input("markers", MarkerFrame, "labelled markers, m, world")
    smoothed = Output("smoothed_markers", MarkerFrame, "the same markers smoothed, m, world")
    alpha = Param(0.5, "weight of the newest frame, 0..1 (1: no smoothing)", minimum=0.0, maximum=1.0)

    def on_markers(self, frame: MarkerFrame) -> None:
        new = np.where(frame.valid[:, None], frame.positions, np.nan)
        last = getattr(self, "_last", None)
        if last is None or last.shape != new.shape:
            last = new
        mixed = self.alpha * new + (1.0 - self.alpha) * last
        self._last = np.where(np.isnan(last), new, mixed)   # a marker seen again starts from itself
        self.smoothed.publish(MarkerFrame(frame_number=frame.frame_number, rate_hz=frame.rate_hz,
                                          positions=self._last, valid=frame.valid, residual=frame.residual),
                              self.markers.envelope.capture_ns)
