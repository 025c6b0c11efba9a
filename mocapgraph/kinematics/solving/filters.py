"""Per-frame temporal stages for joint positions: short-gap prediction and smoothing filters.

All work on float[N,3] points with a time in seconds, one frame per ``step`` call, so live and
batch use the same code. NaN inputs never crash: a missing point resets that point's state.
"""
from __future__ import annotations

import numpy as np

from mocapgraph.kinematics.model import Quality


class GapFiller:
    """Constant-velocity prediction over short gaps.

    A point that goes missing is extrapolated from its last measured position and an
    exponentially smoothed velocity for at most ``max_gap_s`` seconds (quality ESTIMATED);
    after that it is NaN + MISSING. ``max_gap_s = 0`` disables prediction.
    """

    def __init__(self, n: int, max_gap_s: float, velocity_smoothing: float = 0.5) -> None:
        self.max_gap_s = float(max_gap_s)
        self.alpha = float(velocity_smoothing)
        self.last = np.full((n, 3), np.nan)
        self.vel = np.zeros((n, 3))
        self.t_last = np.full(n, -np.inf)
        self.fresh = np.zeros(n, dtype=bool)  # last step was measured (velocity can update)
        self._steady = False  # every point measured at the same last time

    def step(self, x: np.ndarray, quality: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """x: float[N,3] measured (NaN = missing), quality int8[N]; returns filled copies."""
        meas = quality != Quality.MISSING
        if self._steady and meas.all():
            # Common case: everything measured now and last frame; only the velocity moves.
            dt = t - self.t_last[0]
            if dt > 0:
                self.vel *= 1.0 - self.alpha
                self.vel += (self.alpha / dt) * (x - self.last)
            self.last[:] = x
            self.t_last[:] = t
            return x, quality
        dt = t - self.t_last
        upd = meas & self.fresh & (dt > 0)
        if upd.any():
            v_new = (x[upd] - self.last[upd]) / dt[upd, None]
            self.vel[upd] = self.alpha * v_new + (1.0 - self.alpha) * self.vel[upd]
        self.vel[meas & ~self.fresh] = 0.0
        gap = ~meas & (dt <= self.max_gap_s + 1e-9) & np.isfinite(self.last[:, 0])
        x = x.copy()
        q = quality.copy()
        if gap.any():
            x[gap] = self.last[gap] + self.vel[gap] * dt[gap, None]
            q[gap] = Quality.ESTIMATED
        self.last[meas] = x[meas]
        self.t_last[meas] = t
        self.fresh = meas
        self._steady = bool(meas.all()) and bool((self.t_last == t).all())
        return x, q


class OneEuroFilter:
    """One-euro filter (Casiez et al. 2012) on 3D points; cutoff rises with speed (m/s)."""

    def __init__(self, n: int, min_cutoff_hz: float = 1.0, beta: float = 0.5,
                 d_cutoff_hz: float = 1.0) -> None:
        self.min_cutoff = float(min_cutoff_hz)
        self.beta = float(beta)
        self.d_cutoff = float(d_cutoff_hz)
        self.x = np.full((n, 3), np.nan)
        self.dx = np.zeros((n, 3))
        self.t = np.full(n, np.nan)

    @staticmethod
    def _alpha(dt: np.ndarray, cutoff: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + 1.0 / (2.0 * np.pi * cutoff * dt))

    def step(self, x: np.ndarray, t: float) -> np.ndarray:
        ok = np.isfinite(x).all(1)
        run = ok & np.isfinite(self.x[:, 0]) & (t > self.t)
        out = x.copy()
        if run.any():
            dt = (t - self.t[run])[:, None]
            dx = (x[run] - self.x[run]) / dt
            self.dx[run] += self._alpha(dt, self.d_cutoff) * (dx - self.dx[run])
            cutoff = self.min_cutoff + self.beta * np.linalg.norm(self.dx[run], axis=1, keepdims=True)
            out[run] = self.x[run] + self._alpha(dt, cutoff) * (x[run] - self.x[run])
        reset = ok & ~run
        self.dx[reset] = 0.0
        self.x[ok] = out[ok]
        self.t[ok] = t
        self.x[~ok] = np.nan
        return out


class AlphaBetaFilter:
    """Constant-velocity (alpha-beta) tracker on 3D points; NaN input resets the point."""

    def __init__(self, n: int, alpha: float = 0.5, beta: float = 0.1) -> None:
        self.a = float(alpha)
        self.b = float(beta)
        self.x = np.full((n, 3), np.nan)
        self.v = np.zeros((n, 3))
        self.t = np.full(n, np.nan)

    def step(self, x: np.ndarray, t: float) -> np.ndarray:
        ok = np.isfinite(x).all(1)
        run = ok & np.isfinite(self.x[:, 0]) & (t > self.t)
        out = x.copy()
        if run.any():
            dt = (t - self.t[run])[:, None]
            pred = self.x[run] + self.v[run] * dt
            r = x[run] - pred
            out[run] = pred + self.a * r
            self.v[run] += self.b * r / dt
        reset = ok & ~run
        self.v[reset] = 0.0
        self.x[ok] = out[ok]
        self.t[ok] = t
        self.x[~ok] = np.nan
        return out


def make_filter(kind: str | None, n: int, **params: float) -> OneEuroFilter | AlphaBetaFilter | None:
    """``None``/"none", "one_euro" or "constant_velocity" (alpha-beta)."""
    if kind in (None, "", "none"):
        return None
    if kind == "one_euro":
        return OneEuroFilter(n, **params)
    if kind in ("constant_velocity", "alpha_beta"):
        return AlphaBetaFilter(n, **params)
    raise ValueError(f"unknown filter '{kind}' (expected none, one_euro or constant_velocity)")
