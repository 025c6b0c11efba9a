"""TRC replay node: an OpenSim / Motion Analysis TRC file's markers as live MarkerFrames."""
from __future__ import annotations

from pathlib import Path

from ..formats import MarkerTrial, read_trc
from .marker_source import MarkerFilePlayer


class TRCReader(MarkerFilePlayer):
    """Replays a TRC file as ``markers`` + latched ``marker_layout``.

    The header's units become metres and the file's up axis (``up_axis``; 'auto' = +Y, OpenSim's convention)
    becomes world Z; blank or ``nan`` fields are missing markers. A missing file or a broken
    header is reported in one line and the node exits with code 1.
    """

    summary = "replay a TRC file's markers (real time or faster, loop, frame range, unit/axis conversion)"

    has_residuals = False  # TRC carries positions only

    def read_trial(self, path: Path) -> MarkerTrial:
        return read_trc(path, up_axis=self.up_axis)
