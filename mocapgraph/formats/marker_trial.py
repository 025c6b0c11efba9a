"""MarkerTrial: labelled 3-D marker trajectories as every marker reader returns them.

Frame and units are fixed whatever the file held: metres, world frame (right-handed, Z up,
X forward), NaN where a marker is missing. What the reader converted to get there is listed
in plain sentences in ``conversions``; anything odd it tolerated is in ``notes``.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Iterable

import numpy as np


@dataclass
class MarkerTrial:
    """Marker trajectories of one capture.

    labels: marker names, in file order (whitespace stripped, case kept).
    positions: float64 [T, M, 3], metres, world frame; NaN where missing.
    residuals: float64 [T, M], metres (the capture system's fit residual; 0 when the
        file has none); NaN where missing.
    rate_hz: frames per second.
    first_frame: number of the first frame as the capture software shows it
        (C3D: 1-based header frame; TRC: the first Frame# value).
    source: where the data came from (file path or a description).
    conversions: sentences saying what was converted, e.g. "units mm -> m".
    notes: other things the reader noticed and tolerated (library warnings, padding...).
    model_outputs: label -> float64 [T, 3] for computed channels that are not markers
        (Vicon angles, forces, segment axes...). See ``model_output_kinds`` for each one's
        meaning and units.
    model_output_kinds: label -> short description with units, e.g. "angle [rad]",
        "position [m, world]", "force [N]".
    extra: free-form metadata (e.g. the original axis mapping), never needed to use the data.
    """

    labels: list[str]
    positions: np.ndarray
    residuals: np.ndarray
    rate_hz: float
    first_frame: int = 1
    source: str = ""
    conversions: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    model_outputs: dict[str, np.ndarray] = field(default_factory=dict)
    model_output_kinds: dict[str, str] = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.labels = [str(s) for s in self.labels]
        self.positions = np.asarray(self.positions, dtype=np.float64)
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise ValueError(f"positions must be [T, M, 3], got {self.positions.shape}")
        T, M, _ = self.positions.shape
        if len(self.labels) != M:
            raise ValueError(f"{len(self.labels)} labels for {M} markers")
        if self.residuals is None:
            self.residuals = np.where(np.isnan(self.positions[..., 0]), np.nan, 0.0)
        self.residuals = np.asarray(self.residuals, dtype=np.float64)
        if self.residuals.shape != (T, M):
            raise ValueError(f"residuals must be [{T}, {M}], got {self.residuals.shape}")
        if not (self.rate_hz > 0):
            raise ValueError(f"rate_hz must be positive, got {self.rate_hz}")
        self.rate_hz = float(self.rate_hz)
        self.first_frame = int(self.first_frame)

    # ---- sizes and time -------------------------------------------------------------
    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    @property
    def duration_s(self) -> float:
        """Time from the first to the last frame, seconds."""
        return max(self.n_frames - 1, 0) / self.rate_hz

    @property
    def times_s(self) -> np.ndarray:
        """float64 [T] seconds since the first frame."""
        return np.arange(self.n_frames, dtype=np.float64) / self.rate_hz

    @property
    def file_times_s(self) -> np.ndarray:
        """float64 [T] seconds on the file's own clock: its time column when it has one (TRC
        ``Time``, kept in ``extra["time_s"]``), else frame ``first_frame`` at
        ``(first_frame - 1) / rate_hz`` (C3D frame 1 is t = 0; a 0-based first frame 0 is t = 0
        too), so a trial that starts 0.23 s into the capture says so."""
        t = self.extra.get("time_s")
        if t is not None:
            t = np.asarray(t, dtype=np.float64)
            if t.shape == (self.n_frames,) and np.all(np.isfinite(t)):
                return t
        return (max(self.first_frame - 1, 0) + np.arange(self.n_frames, dtype=np.float64)) / self.rate_hz

    @property
    def timestamps_ns(self) -> np.ndarray:
        """int64 [T] nanoseconds since the first frame (rounded)."""
        return np.round(np.arange(self.n_frames) * (1e9 / self.rate_hz)).astype(np.int64)

    @property
    def valid(self) -> np.ndarray:
        """bool [T, M]: True where the marker has a position."""
        return ~np.isnan(self.positions).any(axis=2)

    @property
    def gap_fraction(self) -> float:
        """Share of marker samples that are missing, 0..1."""
        return float(1.0 - self.valid.mean()) if self.positions.size else 0.0

    # ---- lookup ---------------------------------------------------------------------
    def index(self, label: str) -> int:
        """Column of ``label`` (exact match first, then case-insensitive); KeyError if absent."""
        if label in self.labels:
            return self.labels.index(label)
        low = [s.lower() for s in self.labels]
        key = label.strip().lower()
        if key in low:
            return low.index(key)
        raise KeyError(f"no marker {label!r} in {self.source or 'trial'}")

    def __contains__(self, label: object) -> bool:
        try:
            self.index(str(label))
            return True
        except KeyError:
            return False

    def marker(self, label: str) -> np.ndarray:
        """float64 [T, 3] trajectory of one marker (a view)."""
        return self.positions[:, self.index(label)]

    def select(self, labels: Iterable[str], *, missing: str = "raise") -> "MarkerTrial":
        """New trial holding only ``labels`` (case-insensitive), in the order given.

        missing: "raise" -> KeyError for an absent label; "nan" -> an all-NaN column;
        "drop" -> leave it out.
        """
        cols: list[int | None] = []
        names: list[str] = []
        for lab in labels:
            try:
                i = self.index(lab)
            except KeyError:
                if missing == "raise":
                    raise
                if missing == "drop":
                    continue
                i = None
            cols.append(i)
            names.append(self.labels[i] if i is not None else lab)
        pos = np.full((self.n_frames, len(cols), 3), np.nan)
        res = np.full((self.n_frames, len(cols)), np.nan)
        have = [k for k, i in enumerate(cols) if i is not None]
        idx = [cols[k] for k in have]
        pos[:, have] = self.positions[:, idx]
        res[:, have] = self.residuals[:, idx]
        return replace(self, labels=names, positions=pos, residuals=res,
                       conversions=list(self.conversions), notes=list(self.notes))

    def frames(self, start: int, stop: int | None = None) -> "MarkerTrial":
        """New trial holding frames [start, stop) (0-based indices into this trial)."""
        sl = slice(start, stop)
        first = self.first_frame + (range(self.n_frames)[sl].start if self.n_frames else 0)
        extra = dict(self.extra)
        if extra.get("time_s") is not None and len(extra["time_s"]) == self.n_frames:
            extra["time_s"] = np.asarray(extra["time_s"])[sl].copy()
        return replace(self, positions=self.positions[sl].copy(), extra=extra,
                       residuals=self.residuals[sl].copy(), first_frame=first,
                       model_outputs={k: v[sl].copy() for k, v in self.model_outputs.items()},
                       conversions=list(self.conversions), notes=list(self.notes))

    def summary(self) -> str:
        """One line for logs: counts, rate, gaps, conversions."""
        conv = "; ".join(self.conversions) or "no conversion"
        return (f"{self.n_markers} markers x {self.n_frames} frames @ {self.rate_hz:g} Hz, "
                f"{100 * self.gap_fraction:.1f}% gaps ({conv})")
