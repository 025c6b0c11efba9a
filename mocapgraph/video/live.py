"""Live cameras' landmark frames grouped by their capture time stamps, for triangulation (pure).

:class:`FrameGrouper` takes each camera's frames as they arrive (capture stamp, frame number,
landmarks) and hands out groups: the frames of different cameras whose capture stamps lie within
half a frame period of the group's earliest frame. A group is complete when every camera has given
its frame, or has moved past the group's time (it skipped that instant: counted ``missed``), or
when ``wait_s`` has passed since the group's capture time (the cameras not in it are counted
``lagging``). A camera silent for ``stall_s`` is stalled: named, not waited for, and the others
continue; it rejoins with its next frame. A frame older than the last group handed out is
``late`` (counted, dropped). State is bounded: at most ``max_pending`` frames per camera.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np


@dataclass
class FrameGroup:
    """Frames of several cameras taken at one instant: uv [C, N, 2] px (NaN: camera absent),
    conf [C, N] (0: absent), frames [C] frame numbers (-1: absent), capture_ns of the earliest."""

    capture_ns: int
    uv: np.ndarray
    conf: np.ndarray
    frames: np.ndarray

    @property
    def present(self) -> np.ndarray:
        return self.frames >= 0


@dataclass
class CameraCounts:
    """What became of one camera's frames."""

    received: int = 0
    grouped: int = 0
    missed: int = 0          # groups it skipped (it moved past their time)
    lagging: int = 0         # groups handed out without it because it was late
    late: int = 0            # its frames that came after their group had gone
    stalled: bool = False
    last_arrival_ns: int = 0
    notes: list[str] = field(default_factory=list)


class FrameGrouper:
    """Groups N cameras' frames by capture time (see the module note)."""

    def __init__(self, names: list[str], n_points: int, period_s: float, *, wait_s: float = 0.5,
                 stall_s: float = 2.0, max_pending: int = 256) -> None:
        self.names = list(names)
        self.n_points = int(n_points)
        self.tol_ns = int(round(0.5 * period_s * 1e9))
        self.wait_ns = int(round(wait_s * 1e9))
        self.stall_ns = int(round(stall_s * 1e9))
        self.pending: list[deque] = [deque(maxlen=max_pending) for _ in names]
        self.newest_ns = np.full(len(names), -1, dtype=np.int64)      # newest capture stamp seen per camera
        self.counts = [CameraCounts() for _ in names]
        self.last_group_ns: int | None = None
        self.groups = 0
        self.first_arrival_ns = 0

    def set_rate(self, rate_hz: float) -> None:
        """The cameras' frame rate (the slowest's): frames within half its period are one instant."""
        if rate_hz > 0:
            self.tol_ns = int(round(0.5e9 / rate_hz))

    def add(self, cam: int, capture_ns: int, frame: int, uv: np.ndarray, conf: np.ndarray, now_ns: int) -> list[str]:
        """Take one frame of camera ``cam``; returns notes (a stalled camera back)."""
        c = self.counts[cam]
        c.received += 1
        c.last_arrival_ns = now_ns
        self.first_arrival_ns = self.first_arrival_ns or now_ns
        notes = []
        if c.stalled:
            c.stalled = False
            notes.append(f"camera {self.names[cam]} is back (frame {frame})")
        if self.last_group_ns is not None and capture_ns <= self.last_group_ns + self.tol_ns:
            c.late += 1
            return notes
        q = self.pending[cam]
        if q and capture_ns <= q[-1][0]:            # not after its previous frame: out of order
            c.late += 1
            return notes
        q.append((int(capture_ns), int(frame), np.asarray(uv, dtype=np.float64), np.asarray(conf, dtype=np.float64)))
        self.newest_ns[cam] = max(self.newest_ns[cam], capture_ns)
        return notes

    def _check_stalls(self, now_ns: int) -> list[str]:
        notes = []
        for k, c in enumerate(self.counts):
            last = c.last_arrival_ns or self.first_arrival_ns      # never heard: since the first camera's frame
            if not c.stalled and last and now_ns - last > self.stall_ns:
                c.stalled = True
                notes.append(f"camera {self.names[k]} stalled: no frame for {(now_ns - last) / 1e9:.1f} s "
                             f"(the others continue)")
        return notes

    def ready(self, now_ns: int) -> tuple[list[FrameGroup], list[str]]:
        """The groups complete at ``now_ns`` (oldest first) and notes on cameras stalled."""
        notes = self._check_stalls(now_ns)
        out = []
        while True:
            heads = [q[0][0] if q else None for q in self.pending]
            stamps = [h for h in heads if h is not None]
            if not stamps:
                return out, notes
            t_a = min(stamps)
            member = [h is not None and h - t_a <= self.tol_ns for h in heads]
            waiting = [k for k, c in enumerate(self.counts)
                       if not member[k] and not c.stalled and self.newest_ns[k] <= t_a + self.tol_ns]
            if waiting and now_ns - t_a < self.wait_ns:
                return out, notes
            C = len(self.names)
            uv = np.full((C, self.n_points, 2), np.nan)
            conf = np.zeros((C, self.n_points))
            frames = np.full(C, -1, dtype=np.int64)
            for k in range(C):
                c = self.counts[k]
                if member[k]:
                    _, frames[k], uv[k], conf[k] = self.pending[k].popleft()
                    c.grouped += 1
                elif k in waiting:
                    c.lagging += 1
                else:
                    c.missed += 1
            self.last_group_ns = t_a
            self.groups += 1
            out.append(FrameGroup(t_a, uv, conf, frames))

    def status(self) -> dict[str, dict[str, int | bool]]:
        """Per camera: received, grouped, missed, lagging, late, stalled."""
        return {n: {"received": c.received, "grouped": c.grouped, "missed": c.missed, "lagging": c.lagging,
                    "late": c.late, "stalled": c.stalled} for n, c in zip(self.names, self.counts)}
