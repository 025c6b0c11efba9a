"""Mapping a device's clock onto ours: offset and drift estimated continuously by minimum-delay filtering.

A device stamps each frame with its own clock; we see the frame arrive later by a transport delay
that varies (network, USB, scheduling) but is never negative. So in the plane of (device time x,
arrival minus device time y), every sample lies on or above the true line ``y = offset + drift*x``,
and the samples that came through fastest sit right on it. :class:`ClockSync` finds that lower
envelope, as NTP's clock filter and LabStreamingLayer's time correction do:

- **Minimum-delay windows**: device time is cut into windows of ``window_s``; each keeps only its
  fastest sample. The last ``history_s`` of window minima are kept (bounded memory: at most
  ``history_s / window_s`` points, whatever the frame rate).
- **Line under the points** (offset and drift): when a window closes, the line through the
  minima is the one that lies under every point and is as high as it can be on average (the
  linear-programming estimate of Moon, Skelly and Towsley for one-way delays): it is the edge of
  the points' lower convex hull over their mean device time. Until the minima span
  ``drift_span_s`` the drift is not estimated (taken as 0: the line is the lowest point);
  the drift is clamped to ``max_drift_ppm``.
- **Faster sample, lower line**: a sample that arrives earlier than the line says it could have
  (less delay than any before) lowers the line at once, so the first seconds improve frame by
  frame instead of keeping the first frame's delay baked in.
- **Clock reset** (the device restarted or its clock jumped): device time going back by more than
  ``reset_s``, or a frame arriving more than ``reset_s`` *before* the line says it was sent,
  re-seeds the estimate at once; frames arriving more than ``reset_s`` late for ``confirm_s`` on
  end (a clock that stood still) re-seed too, while a shorter stall (a network hiccup) does not.
  Re-seeds are counted (``resets``); :meth:`ClockSync.forget` re-seeds without counting (a stream
  reopened on purpose).

Capture time = the device time mapped by the line, minus the frame's ``latency_ns`` where the
protocol says how long before its time stamp the frame was exposed (mid-exposure: give the time
from mid-exposure to the stamp). A constant part of the transport delay cannot be told from the
offset by one-way timing: the estimate maps each stamp to when the *fastest* frames arrived
(for a device on a LAN, within tens of microseconds of the truth).

Use::

    sync = ClockSync()
    capture_ns = sync.update(device_ns, arrival_ns)            # per frame, our clock's ns
    capture_ns = sync.update(device_ns, arrival_ns, latency_ns=exposure_to_stamp_ns)
    sync.stats()   # ClockStats: offset_ns, drift_ppm, jitter_ms, delay_ms, resets, ...

``arrival_ns`` is our clock when the frame arrived (``time.time_ns()``, as every capture stamp of
the bus). Pure Python on integers and floats, O(1) per frame, a hull of at most a few hundred
points per window; no I/O, no bus.
"""
from __future__ import annotations

import math
import os
import time
from collections import deque
from dataclasses import asdict, dataclass
from typing import Any

#: Tests only: this process's clock reads this many ns off the kernel's (two "machines" sharing
#: one kernel in network namespaces). Bus stamps (publish, receive) and the launcher's clock
#: exchange read :func:`wall_ns`; 0 (unset) makes it ``time.time_ns`` itself.
TEST_OFFSET_NS = int(os.environ.get("MOCAPGRAPH_TEST_CLOCK_OFFSET_NS", "0") or 0)


def _offset_wall_ns() -> int:
    return time.time_ns() + TEST_OFFSET_NS


wall_ns = _offset_wall_ns if TEST_OFFSET_NS else time.time_ns


@dataclass(frozen=True)
class ClockStats:
    """What the estimate says now (NaN / 0 before the first sample)."""

    #: our clock minus the device's at the latest sample, ns (capture = device time + offset - latency)
    offset_ns: int
    #: how much faster the device's clock runs than ours, parts per million
    drift_ppm: float
    #: standard deviation of the transport delay above the fastest frames, ms
    jitter_ms: float
    #: mean transport delay above the fastest frames, ms
    delay_ms: float
    samples: int
    resets: int
    #: window minima the line rests on, and the device time they span, s
    points: int
    span_s: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def lower_hull(xs: list[float], ys: list[float]) -> list[int]:
    """Indices of the lower convex hull of points sorted by x (Andrew's monotone chain)."""
    hull: list[int] = []
    for i in range(len(xs)):
        while len(hull) >= 2:
            o, a = hull[-2], hull[-1]
            if (xs[a] - xs[o]) * (ys[i] - ys[o]) - (ys[a] - ys[o]) * (xs[i] - xs[o]) <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return hull


def line_under(xs: list[float], ys: list[float]) -> tuple[float, float]:
    """(a, b) of the line y = a + b*x under every point, highest at the points' mean x: the hull
    edge over the mean (the one-way-delay LP estimate). Needs 2+ points with distinct x."""
    hull = lower_hull(xs, ys)
    xm = sum(xs) / len(xs)
    for i, j in zip(hull, hull[1:]):
        if xs[j] >= xm:
            b = (ys[j] - ys[i]) / (xs[j] - xs[i])
            return ys[i] - b * xs[i], b
    i = hull[-1]
    return ys[i], 0.0


class ClockSync:
    """One device clock mapped onto ours (see module doc): ``update(device_ns, arrival_ns) -> capture_ns``."""

    def __init__(self, window_s: float = 0.5, history_s: float = 60.0, drift_span_s: float = 6.0,
                 max_drift_ppm: float = 500.0, reset_s: float = 0.5, confirm_s: float = 1.0,
                 jitter_alpha: float = 1 / 256) -> None:
        self.window_ns = int(window_s * 1e9)
        self.max_points = max(2, int(math.ceil(history_s / window_s)))
        self.drift_span_ns = drift_span_s * 1e9
        self.max_drift = max_drift_ppm * 1e-6
        self.reset_ns = reset_s * 1e9
        self.confirm_ns = confirm_s * 1e9
        self.alpha = float(jitter_alpha)
        self.samples = 0
        self.resets = 0
        self._seeded = False
        self._forget_state()

    # ----- state ------------------------------------------------------------------------------
    def _forget_state(self) -> None:
        self._seeded = False
        self._dev0 = 0        # device ns of the seed: x = device - dev0
        self._off0 = 0        # arrival - device of the seed: y = arrival - device - off0
        self._a = 0.0         # the line, y = a + b*x (ns, ns/ns)
        self._b = 0.0
        self._points: deque[tuple[float, float]] = deque(maxlen=self.max_points)
        self._win = 0         # current window index and its fastest sample
        self._win_min: tuple[float, float] | None = None
        self._last_x = 0.0
        self._late_since: int | None = None   # arrival ns of the first frame of a late run
        self._d_mean = 0.0
        self._d_var = 0.0
        self._last_offset = 0

    def forget(self) -> None:
        """Start again from the next sample without counting a reset (the stream was reopened)."""
        self._forget_state()

    def _seed(self, device_ns: int, arrival_ns: int) -> None:
        self._forget_state()
        self._seeded = True
        self._dev0 = device_ns
        self._off0 = arrival_ns - device_ns
        self._win_min = (0.0, 0.0)

    # ----- per frame --------------------------------------------------------------------------
    def update(self, device_ns: int, arrival_ns: int, latency_ns: int = 0) -> int:
        """Take one (device time, arrival time) pair; return the frame's capture time on our clock,
        ns: device time mapped by the estimate, minus ``latency_ns`` (stamp after mid-exposure)."""
        device_ns, arrival_ns = int(device_ns), int(arrival_ns)
        self.samples += 1
        if not self._seeded:
            self._seed(device_ns, arrival_ns)
        x = float(device_ns - self._dev0)
        y = float(arrival_ns - device_ns - self._off0)
        d = y - (self._a + self._b * x)          # delay above the line
        if x < self._last_x - self.reset_ns or d < -self.reset_ns or self._stalled(d, arrival_ns):
            self.resets += 1
            self._seed(device_ns, arrival_ns)
            x = y = d = 0.0
        if d > self.reset_ns:                    # a late frame (network stall?): mapped, not learnt from
            return self._capture(device_ns, x, latency_ns)
        self._last_x = max(self._last_x, x)
        self._take(x, y)
        below = y - (self._a + self._b * x)
        if below < 0:                            # faster than any before: the line comes down
            self._a += below
        d = max(d, 0.0)
        self._d_mean += self.alpha * (d - self._d_mean)
        self._d_var += self.alpha * ((d - self._d_mean) ** 2 - self._d_var)
        return self._capture(device_ns, x, latency_ns)

    def _stalled(self, d: float, arrival_ns: int) -> bool:
        """True once frames have arrived more than reset_s late for confirm_s on end."""
        if d <= self.reset_ns:
            self._late_since = None
            return False
        if self._late_since is None:
            self._late_since = arrival_ns
        return arrival_ns - self._late_since >= self.confirm_ns

    def _capture(self, device_ns: int, x: float, latency_ns: int) -> int:
        self._last_offset = self._off0 + round(self._a + self._b * x)
        return device_ns + self._last_offset - int(latency_ns)

    def _take(self, x: float, y: float) -> None:
        """The sample into its window; a window closing refits the line."""
        win = int(x // self.window_ns)
        if win > self._win:
            self._points.append(self._win_min)
            self._win, self._win_min = win, (x, y)
            self._refit()
        elif win == self._win:
            if y < self._win_min[1]:
                self._win_min = (x, y)
        elif win == self._win - 1 and self._points and y < self._points[-1][1]:
            self._points[-1] = (x, y)            # overtaken on the way: still its window's fastest

    def _refit(self) -> None:
        pts = list(self._points) + [self._win_min]
        xs = [p[0] for p in pts]
        ys = [p[1] for p in pts]
        if xs[-1] - xs[0] >= self.drift_span_ns:
            b = max(-self.max_drift, min(self.max_drift, line_under(xs, ys)[1]))
            self._a, self._b = min(y - b * x for x, y in pts), b
        else:   # drift not known yet: the lowest point of the last few seconds (drift adds little)
            self._a, self._b = min(y for x, y in pts if x >= xs[-1] - self.drift_span_ns / 3), 0.0

    # ----- reporting --------------------------------------------------------------------------
    def stats(self) -> ClockStats:
        pts = list(self._points)
        span = (pts[-1][0] - pts[0][0]) / 1e9 if len(pts) > 1 else 0.0
        seen = self.samples > 0
        return ClockStats(offset_ns=self._last_offset,
                          drift_ppm=-self._b / (1.0 + self._b) * 1e6 if seen else math.nan,
                          jitter_ms=math.sqrt(max(self._d_var, 0.0)) / 1e6 if seen else math.nan,
                          delay_ms=self._d_mean / 1e6 if seen else math.nan,
                          samples=self.samples, resets=self.resets, points=len(pts), span_s=span)


@dataclass(frozen=True)
class PeerStats:
    """Another machine's clock as :class:`PeerClock` sees it (NaN before the first exchange)."""

    #: the peer's clock minus ours, ns (from the exchange of least round trip)
    offset_ns: float
    #: that exchange's round trip less the peer's turnaround, ms (the offset is good to half of it)
    delay_ms: float
    #: standard deviation of the kept exchanges' offsets, ms
    jitter_ms: float
    samples: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


class PeerClock:
    """Another machine's clock from two-way exchanges (NTP's on-wire arithmetic and clock filter).

    ``update(t1, t2, t3, t4)``: we sent at t1 (our clock), the peer received at t2 and answered at
    t3 (its clock), we received at t4. Offset = ((t2 - t1) + (t3 - t4)) / 2, exact when the two
    ways take equally long; delay = (t4 - t1) - (t3 - t2). Of the last ``keep`` exchanges the one
    with the least delay gives the offset (queueing only ever adds delay, and asymmetry with it).
    """

    def __init__(self, keep: int = 16) -> None:
        self._kept: deque[tuple[int, float]] = deque(maxlen=keep)   # (delay ns, offset ns)
        self.samples = 0

    def update(self, t1: int, t2: int, t3: int, t4: int) -> None:
        delay = (t4 - t1) - (t3 - t2)
        if delay < 0 or t3 < t2:
            return                       # not a real exchange (a clock stepped mid-way)
        self._kept.append((delay, ((t2 - t1) + (t3 - t4)) / 2))
        self.samples += 1

    def stats(self) -> PeerStats:
        if not self._kept:
            return PeerStats(math.nan, math.nan, math.nan, 0)
        delay, offset = min(self._kept)
        offs = [o for _, o in self._kept]
        mean = sum(offs) / len(offs)
        jitter = math.sqrt(sum((o - mean) ** 2 for o in offs) / len(offs))
        return PeerStats(offset, delay / 1e6, jitter / 1e6, self.samples)
