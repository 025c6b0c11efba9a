"""SkeletonTrial: joint trajectories of a skeleton stream (Kinect, BVH playback...).

Whatever the source: metres, world frame (right-handed, Z up, X forward), quaternions
(w, x, y, z), integer-nanosecond time stamps, NaN where a joint is missing.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


NOT_TRACKED = 0
INFERRED = 1
TRACKED = 2


@dataclass
class SkeletonTrial:
    """Joint positions (and optionally orientations) over time.

    names: joint names [J].
    parents: int [J], index of each joint's parent, -1 for a root. A parent may come after
        its child (the Kinect v2 joint order does that); ``topological_order`` gives an
        order with parents first.
    positions: float64 [T, J, 3] metres, world frame; NaN where missing.
    tracking_state: int8 [T, J]: 0 not tracked, 1 inferred, 2 tracked.
    timestamps_ns: int64 [T] capture time stamps (source clock, nanoseconds).
    rate_hz: nominal or estimated frame rate.
    orientations: float64 [T, J, 4] world orientation quaternions (w, x, y, z), or None
        when the source gives none.
    """

    names: list[str]
    parents: np.ndarray
    positions: np.ndarray
    tracking_state: np.ndarray
    timestamps_ns: np.ndarray
    rate_hz: float
    orientations: np.ndarray | None = None
    source: str = ""
    conversions: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.names = [str(n) for n in self.names]
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.positions = np.asarray(self.positions, dtype=np.float64)
        T, J = self.positions.shape[:2]
        if self.positions.shape != (T, J, 3) or len(self.names) != J or self.parents.shape != (J,):
            raise ValueError(f"inconsistent shapes: {len(self.names)} names, parents "
                             f"{self.parents.shape}, positions {self.positions.shape}")
        self.topological_order = topological_order(self.parents)
        self.tracking_state = np.asarray(self.tracking_state, dtype=np.int8)
        self.timestamps_ns = np.asarray(self.timestamps_ns, dtype=np.int64)
        if self.tracking_state.shape != (T, J) or self.timestamps_ns.shape != (T,):
            raise ValueError("tracking_state must be [T, J] and timestamps_ns [T]")
        if self.orientations is not None:
            self.orientations = np.asarray(self.orientations, dtype=np.float64)
            if self.orientations.shape != (T, J, 4):
                raise ValueError(f"orientations must be [{T}, {J}, 4]")
        self.rate_hz = float(self.rate_hz)

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_joints(self) -> int:
        return int(self.positions.shape[1])

    @property
    def times_s(self) -> np.ndarray:
        """float64 [T] seconds since the first frame."""
        return (self.timestamps_ns - self.timestamps_ns[0]) * 1e-9 if self.n_frames else np.zeros(0)

    def index(self, name: str) -> int:
        """Joint index by name (exact, then case-insensitive); KeyError if absent."""
        if name in self.names:
            return self.names.index(name)
        low = [n.lower() for n in self.names]
        if name.lower() in low:
            return low.index(name.lower())
        raise KeyError(f"no joint {name!r}")

    def joint(self, name: str) -> np.ndarray:
        """float64 [T, 3] trajectory of one joint."""
        return self.positions[:, self.index(name)]

    def bone_lengths(self) -> np.ndarray:
        """float64 [T, J]: distance of each joint to its parent (NaN for roots), metres."""
        out = np.full(self.positions.shape[:2], np.nan)
        child = np.flatnonzero(self.parents >= 0)
        d = self.positions[:, child] - self.positions[:, self.parents[child]]
        out[:, child] = np.linalg.norm(d, axis=2)
        return out

    def children(self, j: int) -> list[int]:
        return [int(k) for k in np.flatnonzero(self.parents == j)]


def topological_order(parents: np.ndarray) -> np.ndarray:
    """Joint indices with every parent before its children; ValueError if not a forest."""
    J = len(parents)
    if np.any((parents < -1) | (parents >= J)):
        raise ValueError("parent index out of range")
    depth = np.full(J, -1)
    for j in range(J):
        chain = []
        k = j
        while k >= 0 and depth[k] < 0:
            if k in chain:
                raise ValueError(f"joint parents form a cycle through joint {k}")
            chain.append(k)
            k = parents[k]
        base = depth[k] if k >= 0 else -1
        for n, c in enumerate(reversed(chain)):
            depth[c] = base + 1 + n
    return np.argsort(depth, kind="stable")
