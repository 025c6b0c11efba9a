"""The targets of a physics world: what every joint point and body tracks, and the positional constraints.

Stacked over the characters (rows of :class:`~.index.WorldIndex`): target positions ``p_t`` [N, 3]
m (lifted above the floor) and velocities ``v_t`` m/s, the input as given ``p_in`` / ``v_in`` (what
foot contact is judged by), world orientation targets ``q_t`` [B, 4] wxyz and rates ``w_t`` rad/s,
and two kinds of positional constraint that replace a point's target and hold it still: ``override``
(a hand onto an object, :meth:`TargetState.set_override`, ``reach``) and ``dodge_override`` (the
dodge's, set per frame). NaN: no target. The arrays are the kernels', written in place; ``points``,
``rotations`` and ``inputs`` are them as the tuples :class:`~.controller_kernels.Targets`,
``Orientations`` and ``Inputs``.
"""
from __future__ import annotations

import numpy as np

from . import controller_kernels as ck
from .index import WorldIndex

MAX_RATE = 20.0   # rad/s: faster target orientation rates are clipped


class TargetState:
    """Every character's target (see the module docstring)."""

    def __init__(self, index: WorldIndex, set_target_into, max_target_speed: float) -> None:
        n, b = len(index.pt_body), len(index.b_body)
        self.index = index
        self.p_t = np.full((n, 3), np.nan)
        self.v_t = np.zeros((n, 3))
        self.q_t = np.tile([1.0, 0, 0, 0], (b, 1))
        self.w_t = np.zeros((b, 3))
        self.has_rot = np.zeros(b, dtype=bool)
        self.p_in = np.full((n, 3), np.nan)   # the input targets as given (before lifting), m
        self.v_in = np.zeros((n, 3))          # ... and their velocities, m/s: what foot contact is judged by
        self.override = np.full((n, 3), np.nan)   # positional constraints (reach)
        self.dodge_override = np.full((n, 3), np.nan)
        self.time_of_target: list[float | None] = [None] * len(index.point_slice)
        # as the kernels read them: each kernel is passed the groups it uses (numba types every
        # array passed, every call)
        self.points = tuple(ck.Targets(self.p_t, self.v_t, self.override, self.dodge_override))
        self.rotations = tuple(ck.Orientations(self.q_t, self.w_t, self.has_rot))
        self.inputs = tuple(ck.Inputs(self.p_in, self.v_in))
        self._set_into = set_target_into
        self._limits = (float(max_target_speed), MAX_RATE)

    def set(self, k: int, positions: np.ndarray, orientations: np.ndarray, time_s: float) -> None:
        """Target of character ``k``: joint positions [J, 3] m and world joint orientations [J, 4]
        wxyz (NaN rows: no target for that joint), at input time ``time_s`` s (for the velocities)."""
        ix = self.index
        prev_t = self.time_of_target[k]
        p = np.ascontiguousarray(positions, dtype=np.float64)
        q = np.ascontiguousarray(orientations, dtype=np.float64)
        self._set_into(p, q, ix.joints[k], ix.parents[k], ix.point_slice[k].start, ix.body_slice[k].start,
                       -1.0 if prev_t is None else float(time_s - prev_t), self._limits, ix.pt_min_z, self.points,
                       self.rotations, self.inputs)
        self.time_of_target[k] = time_s

    def set_override(self, point: int, position: np.ndarray | None) -> None:
        """Positional constraint: stacked point ``point`` targets ``position`` (world m) instead of
        its input target, until set to None."""
        self.override[point] = np.nan if position is None else position
