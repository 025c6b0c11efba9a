"""Streaming steps of a calibration capture: find the base pose, sample the gym (capture time, s)."""
from __future__ import annotations

import numpy as np

SEARCHING, FOUND, TIMED_OUT = "searching", "found", "timed_out"


class BasePoseFinder:
    """The first frame in which every marker is visible, within ``timeout_s`` of capture time.

    Feed ``step(ok, t)`` frame by frame (ok: bool[M] marker visible; t: s since the first frame).
    After TIMED_OUT, ``never_seen`` (bool[M]) and ``best_missing`` (bool[M], missing from the most
    complete frame) say why.
    """

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = float(timeout_s)
        self.seen: np.ndarray | None = None
        self.best_missing: np.ndarray | None = None
        self._best_n = -1
        self.progress = 0.0

    def step(self, ok: np.ndarray, t: float) -> str:
        self.seen = ok.copy() if self.seen is None else (self.seen | ok)
        n = int(ok.sum())
        if n > self._best_n:
            self._best_n, self.best_missing = n, ~ok
        if ok.all():
            return FOUND
        if t >= self.timeout_s:
            return TIMED_OUT
        self.progress = t / self.timeout_s
        return SEARCHING

    @property
    def never_seen(self) -> np.ndarray:
        return ~self.seen if self.seen is not None else np.zeros(0, bool)


class GymSampler:
    """The frames of ``seconds`` of capture time, kept at ``rate_hz`` (0: every frame)."""

    def __init__(self, seconds: float, rate_hz: float) -> None:
        self.seconds = float(seconds)
        self.rate_hz = float(rate_hz)
        self.frames: list[np.ndarray] = []
        self._next_k = 0
        self.progress = 0.0

    def step(self, x: np.ndarray, t: float) -> bool:
        """Offer frame ``x`` (float[M,3]) at ``t`` s after the first; True once the capture is
        complete (that frame is not kept)."""
        if t >= self.seconds:
            return True
        k = int(np.floor(t * self.rate_hz + 1e-6)) if self.rate_hz > 0 else self._next_k
        if k >= self._next_k:
            self.frames.append(x)
            self._next_k = k + 1
        self.progress = t / self.seconds
        return False
