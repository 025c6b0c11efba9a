"""A marker input (C3D, TRC, or a bag's MarkerFrame topic) as one MarkerInput, for the batch commands.

Files go through ``formats.sources``; a bag is read here (its MarkerFrame topic and latched
MarkerLayout), as it is already in world axes. Metres, world frame (Z up).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..formats.sources import read_marker_file
from .errors import BagError


@dataclass
class MarkerInput:
    """Markers of one input file: labels, float[T,N,3] m world, rate, frame numbers, layout name."""

    path: Path
    labels: list[str]
    positions: np.ndarray
    rate_hz: float
    frame_numbers: np.ndarray
    layout_name: str = ""
    times_s: np.ndarray | None = None  # float[T] s on the file's own clock (None: from frame numbers)
    notes: list[str] = field(default_factory=list)  # the reader's remarks (duplicate labels...)

    def times(self) -> np.ndarray:
        """float[T] seconds: the file's own times, else frame numbers / rate from the first frame."""
        if self.times_s is not None:
            return self.times_s
        return (self.frame_numbers - self.frame_numbers[0]) / self.rate_hz


def read_marker_input(path: str | Path, topic: str | None = None, up_axis: str = "auto") -> MarkerInput:
    """A C3D, TRC or bag (.mcap) as markers; FormatError / BagError (one line) when it cannot be read.

    topic: a bag's MarkerFrame topic (None: its only one); up_axis: a file's up axis ("auto": what
    the file says); a bag is already in world axes, so anything but "auto" is refused for it.
    """
    p = Path(path)
    if p.suffix.lower() != ".mcap":
        trial = read_marker_file(p, up_axis=up_axis)
        T = trial.positions.shape[0]
        return MarkerInput(p, list(trial.labels), trial.positions, float(trial.rate_hz),
                           trial.first_frame + np.arange(T), "", trial.file_times_s, list(trial.notes))
    if up_axis != "auto":
        raise BagError(p, f"up axis {up_axis!r} applies to C3D and TRC files; a bag is already in world axes (Z up)")
    from .convert import bag_to_marker_trial
    from .reader import BagReader

    with BagReader(p) as reader:
        trial = bag_to_marker_trial(reader, topic)
        name = ""
        lay = [t for t, i in reader.topic_infos().items() if i.type_name == "MarkerLayout" and i.known]
        if lay:
            for _env, m in reader.decoded(lay[0]):
                name = m.name
    T = trial.positions.shape[0]
    return MarkerInput(p, list(trial.labels), trial.positions, float(trial.rate_hz),
                       trial.first_frame + np.arange(T), name, None, list(trial.notes))
