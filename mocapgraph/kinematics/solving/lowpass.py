"""Zero-lag low-pass filtering of marker trajectories, its cutoff chosen by cross-validation.

A batch stage before the solver (``mocapgraph actor solve --lowpass``): a Butterworth filter run
forward and backward (no lag) over every marker coordinate, its cutoff corrected for the two passes
so it is the -3 dB point of the pair (Winter 2009, Biomechanics and Motor Control of Human
Movement, 3.4.4). ``auto`` picks the cutoff that minimises generalised cross-validation (Craven &
Wahba 1979; the criterion of Woltring's GCVSPL): the residual's mean square over (1 - h0)^2, h0 the
filter's own weight on a sample, an estimate of the mean squared error against the true path that
needs no noise level. (Winter's residual analysis chose 5-6.5 Hz on fast arm swings here and cut
their peaks by up to 10 mm.) Each end is extended by a point reflection about a straight line fitted
to its first quarter-period at the cutoff, so a noisy first sample does not pin the output. Each run a
marker is seen is filtered by itself; gaps stay NaN. Positions in metres, rates and cutoffs in Hz.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, filtfilt

ORDER = 2                  # per pass; forward and backward make a zero-lag 4th order
TWO_PASS = 0.802           # cutoff correction for two passes of a 2nd-order Butterworth (Winter)
MIN_FRAMES = 16            # shorter runs are left raw
GRID_STEP_HZ = 0.5         # the finest step between cutoffs GCV tries (Hz)
GCV_BLOCKS, GCV_BLOCK_S = 6, 10.0  # a long trial's cutoff is judged on 6 blocks of 10 s
END_FIT_PERIODS = 0.25     # each end's straight line spans this many periods of the cutoff


@dataclass(frozen=True)
class LowpassReport:
    """What the filter did: cutoff (Hz; None = left raw) and the white-noise standard deviation it
    leaves, a fraction of the input's (what a solver's noise model should be scaled by)."""

    cutoff_hz: float | None
    noise_gain: float


def _coefficients(cutoff_hz: float, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    return butter(ORDER, min(cutoff_hz / TWO_PASS / (0.5 * rate_hz), 0.99))


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True in bool[T]."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return list(zip(edges[::2], edges[1::2]))


def _end_value(x: np.ndarray, n: int) -> np.ndarray:
    """Value at x[0] of the least-squares line through x[:n] (float[T,C] -> float[C])."""
    t = np.arange(n, dtype=float)
    tc = t - t.mean()
    slope = (tc[:, None] * x[:n]).sum(0) / (tc * tc).sum()
    return x[:n].mean(0) - slope * t.mean()


def filter_columns(x: np.ndarray, rate_hz: float, cutoff_hz: float) -> np.ndarray:
    """Zero-lag Butterworth of float[T,C] (no NaN, T >= MIN_FRAMES) along time at a two-pass
    cutoff (Hz), each end point-reflected about its fitted line."""
    T = x.shape[0]
    n = int(min(T, max(4, round(END_FIT_PERIODS * rate_hz / cutoff_hz))))
    pad = int(min(T - 1, round(3 * rate_hz / cutoff_hz)))
    head = 2.0 * _end_value(x, n) - x[pad:0:-1]
    tail = 2.0 * _end_value(x[::-1], n) - x[-2:-pad - 2:-1]
    b, a = _coefficients(cutoff_hz, rate_hz)
    return filtfilt(b, a, np.concatenate([head, x, tail]), axis=0, padtype=None)[pad:pad + T]


def _impulse_response(rate_hz: float, cutoff_hz: float) -> np.ndarray:
    """The two-pass filter's response to a unit sample far from either end."""
    n = int(max(20 * rate_hz / cutoff_hz, 200))
    impulse = np.zeros((2 * n + 1, 1))
    impulse[n] = 1.0
    b, a = _coefficients(cutoff_hz, rate_hz)
    return filtfilt(b, a, impulse, axis=0)[:, 0]


def noise_gain(rate_hz: float, cutoff_hz: float) -> float:
    """Standard deviation of white noise after the filter, as a fraction of before (mid-trial)."""
    return float(np.sqrt((_impulse_response(rate_hz, cutoff_hz) ** 2).sum()))


def _gcv_score(blocks: list[np.ndarray], rate_hz: float, cutoff_hz: float) -> float:
    h = _impulse_response(rate_hz, cutoff_hz)
    own = h[h.size // 2]
    rss = sum(float(((b - filter_columns(b, rate_hz, cutoff_hz)) ** 2).sum()) for b in blocks)
    return rss / sum(b.size for b in blocks) / (1.0 - own) ** 2


def gcv_cutoff(x: np.ndarray, rate_hz: float) -> float:
    """The cutoff (Hz) minimising generalised cross-validation over float[T,C] (no NaN).

    Cutoffs from 1 Hz to 45 % of the rate: a coarse geometric sweep, then 0.5 Hz steps around its
    best. A long trial is judged on up to GCV_BLOCKS evenly spaced blocks of GCV_BLOCK_S seconds.
    """
    T = x.shape[0]
    n = int(GCV_BLOCK_S * rate_hz)
    if T > GCV_BLOCKS * n:
        blocks = [x[a:a + n] for a in np.linspace(0, T - n, GCV_BLOCKS).astype(int)]
    else:
        blocks = [x]
    top = 0.45 * rate_hz
    coarse = np.unique(np.minimum(np.round(np.geomspace(1.0, top, 24) * 2) / 2, top))
    scores = [_gcv_score(blocks, rate_hz, f) for f in coarse]
    k = int(np.argmin(scores))
    lo, hi = coarse[max(k - 1, 0)], coarse[min(k + 1, coarse.size - 1)]
    fine = np.arange(lo, hi + 1e-9, GRID_STEP_HZ)
    fine_scores = [_gcv_score(blocks, rate_hz, f) for f in fine]
    return float(fine[int(np.argmin(fine_scores))])


def lowpass_markers(markers: np.ndarray, rate_hz: float, cutoff_hz: float | str = "auto") -> tuple[np.ndarray, LowpassReport]:
    """float[T,M,3] marker trajectories (m, NaN unseen) -> filtered copy and its report.

    cutoff_hz: a frequency (Hz) or "auto" (generalised cross-validation over the markers seen in
    every frame, else over the longest run one marker is seen; one cutoff for the trial). Each run
    a marker is seen is filtered by itself, so a gap never leaks into the samples beside it; runs
    shorter than MIN_FRAMES stay raw.
    """
    x = np.asarray(markers, dtype=float)
    if cutoff_hz != "auto" and not 0.0 < float(cutoff_hz) < 0.5 * rate_hz:
        raise ValueError(f"low-pass cutoff {float(cutoff_hz):g} Hz must be between 0 and half the rate ({0.5 * rate_hz:g} Hz)")
    seen = np.isfinite(x).all(-1)                                       # [T,M]
    full = seen.all(0)
    runs = {m: [r for r in _runs(seen[:, m]) if r[1] - r[0] >= MIN_FRAMES] for m in np.flatnonzero(~full)}
    if x.shape[0] < MIN_FRAMES or not (full.any() or any(runs.values())):
        return x.copy(), LowpassReport(None, 1.0)
    if cutoff_hz != "auto":
        cutoff = float(cutoff_hz)
    elif full.any():
        cutoff = gcv_cutoff(x[:, full].reshape(x.shape[0], -1), rate_hz)
    else:
        m, (a, b) = max(((m, r) for m, rs in runs.items() for r in rs), key=lambda mr: mr[1][1] - mr[1][0])
        cutoff = gcv_cutoff(x[a:b, m], rate_hz)
    out = x.copy()
    if full.any():
        out[:, full] = filter_columns(x[:, full].reshape(x.shape[0], -1), rate_hz, cutoff).reshape(-1, int(full.sum()), 3)
    for m, rs in runs.items():          # markers with gaps, run by run (a batch stage, not per frame)
        for a, b in rs:
            out[a:b, m] = filter_columns(x[a:b, m], rate_hz, cutoff)
    out[~seen] = np.nan
    return out, LowpassReport(cutoff, noise_gain(rate_hz, cutoff))


class FixedLagLowpass:
    """The same filter live, at a fixed delay: each frame comes out ``lag_frames`` frames late,
    filtered over the frames either side of it (a window of 2 lag + 1, its ends reflected as above).

    ``push(x, tag)`` takes float[M,3] (m, NaN unseen) and any tag (frame number, stamps) and gives
    back the frame ``lag_frames`` earlier with its tag, or None while the window fills. A marker
    missing anywhere in the window comes out as it was measured (raw, or NaN). The last
    ``lag_frames`` frames of a stream wait for frames after them.
    """

    def __init__(self, n_markers: int, rate_hz: float, cutoff_hz: float, lag_frames: int) -> None:
        if not 0.0 < cutoff_hz < 0.5 * rate_hz:
            raise ValueError(f"low-pass cutoff {cutoff_hz:g} Hz must be between 0 and half the rate ({0.5 * rate_hz:g} Hz)")
        if 2 * lag_frames + 1 < MIN_FRAMES:
            raise ValueError(f"a fixed-lag low-pass needs a lag of {MIN_FRAMES // 2} frames or more, got {lag_frames}")
        self.rate_hz, self.cutoff_hz, self.lag = float(rate_hz), float(cutoff_hz), int(lag_frames)
        self._win = np.full((2 * self.lag + 1, n_markers, 3), np.nan)
        self._tags: deque = deque([None] * (2 * self.lag + 1), maxlen=2 * self.lag + 1)
        self._n = 0
        self.noise_gain = noise_gain(rate_hz, cutoff_hz)
        # The filter is linear: on a full window its centre is one fixed weighting of the samples.
        size = 2 * self.lag + 1
        self._weights = filter_columns(np.eye(size), rate_hz, cutoff_hz)[self.lag]

    def reset(self) -> None:
        """Forget the window (a replay looped, a new stream)."""
        self._win[:] = np.nan
        self._tags.extend([None] * self._tags.maxlen)
        self._n = 0

    def push(self, x: np.ndarray, tag=None) -> tuple[np.ndarray, object] | None:
        """This frame in; the frame ``lag`` frames before it out, filtered, with its tag."""
        self._win[:-1] = self._win[1:]
        self._win[-1] = x
        self._tags.append(tag)                     # the oldest drops out (maxlen)
        self._n += 1
        if self._n <= self.lag:
            return None
        if self._n < self._win.shape[0]:           # the stream's first frames: what came so far
            win = self._win[self._win.shape[0] - self._n:]
        else:
            win = self._win
        centre = win.shape[0] - 1 - self.lag
        out = win[centre].copy()
        ok = np.isfinite(win).all((0, 2))          # markers seen in every frame of the window
        if ok.any() and win is self._win:
            out[ok] = np.einsum("w,wmc->mc", self._weights, win[:, ok])
        elif ok.any() and win.shape[0] >= MIN_FRAMES:
            cols = win[:, ok].reshape(win.shape[0], -1)
            out[ok] = filter_columns(cols, self.rate_hz, self.cutoff_hz)[centre].reshape(-1, 3)
        return out, self._tags[-1 - self.lag]
