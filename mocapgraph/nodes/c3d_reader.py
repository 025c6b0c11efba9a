"""C3D replay node: a C3D file's markers as live MarkerFrames (real time or faster, loop, range)."""
from __future__ import annotations

from pathlib import Path

from ..bus import Param
from ..formats import MarkerTrial, read_c3d
from .marker_source import MarkerFilePlayer


class C3DReader(MarkerFilePlayer):
    """Replays a C3D file as ``markers`` + latched ``marker_layout``.

    Units (POINT:UNITS) become metres and the file's up axis (``up_axis``; 'auto' = POINT:Y_SCREEN, else Z)
    becomes world Z; samples coded missing (negative residual or exactly 0,0,0) become NaN with
    valid False. Capture stamps are file time from the moment playback starts. A missing,
    truncated or broken file is reported in one line and the node exits with code 1.
    """

    summary = "replay a C3D file's markers (real time or faster, loop, frame range, unit/axis conversion)"
    include_unlabelled = Param(False, "also pass unlabelled points (*NNN, empty labels) as markers "
                                      "(with a layout they are reported as unplaced)")

    def read_trial(self, path: Path) -> MarkerTrial:
        return read_c3d(path, include_unlabelled=self.include_unlabelled, up_axis=self.up_axis)
