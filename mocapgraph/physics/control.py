"""The controller of a physics world: Eq 1 forces and Eq 2 torques over a frame's substeps (Shum & Ho 6).

Per frame, :meth:`Controller.run` computes Eq 1's per-frame terms (targets moving on at their
velocity between frames) and then, every substep, ``mj_step1``, the control into ``xfrc_applied``
(Eq 2 once a frame, held over its substeps; Eq 1 at every joint point, each bounded), the props'
extra forces (pushes), ``mj_step2``. Gains are the paper's one pair for every joint; the bounds are
per point: the limbs' ``max_force``, the feet's own at the ankles and feet (a light foot driven with
400 N strikes the floor hard) and the trunk's at the root, trunk joints and head (what holds the
body where its target is, as balance does: bounded low, so a push displaces the body rather than
meeting a wall). Eq 2 gains act per unit inertia about the twist axis (1/s^2, 1/s): a foot twisting
with the torso's gains in N·m/rad would be unstable at any usable timestep. SI units, world Z up.
"""
from __future__ import annotations

import math
import time
from typing import Callable

import mujoco
import numpy as np

from ..kinematics.quaternion import quat_to_matrix
from . import controller_kernels as ck
from .anthropometry import bone_masses
from .body import CharacterBody
from .index import WorldIndex
from .params import TrackerParams

TRUNK_CLASSES = ("lower_trunk", "middle_trunk", "upper_trunk", "head")   # anthropometry's segment classes


def tick(profile: dict[str, float], stage: str, since: float) -> float:
    """Add the thread CPU time since ``since`` (s) to ``profile[stage]``; returns now."""
    now = time.thread_time()
    profile[stage] = profile.get(stage, 0.0) + (now - since)
    return now


def force_bounds(bodies: list[CharacterBody], index: WorldIndex, params: TrackerParams) -> np.ndarray:
    """[N] N: the Eq 1 bound of every stacked point (see the module docstring)."""
    g = params.gains
    bound = np.full(len(index.pt_body), g.max_force)
    for k, cb in enumerate(bodies):
        a = index.point_slice[k].start
        ch = cb.character
        classes = bone_masses(ch, cb.body_mass).classes
        trunk = [j for j in range(ch.n_joints) if j == ch.root or classes[j] in TRUNK_CLASSES]
        bound[a + np.array(trunk, dtype=np.int64)] = min(g.max_force, params.trunk_max_force)
        foot = np.r_[cb.feet, ch.parents[cb.feet]].astype(np.int64)
        bound[a + foot] = min(g.max_force, params.foot_max_force)
    return bound


def twist_inertia(m: mujoco.MjModel, index: WorldIndex) -> np.ndarray:
    """[B] kg·m^2: each controlled body's inertia about its twist axis."""
    Rp = quat_to_matrix(m.body_iquat[index.b_body])
    a_p = (np.swapaxes(Rp, 1, 2) @ index.b_axis[:, :, None])[:, :, 0]
    return np.ascontiguousarray((m.body_inertia[index.b_body] * a_p ** 2).sum(1), dtype=np.float64)


class Controller:
    """Bounded PD control of every character of one world (see the module docstring).

    ``frame_terms`` and ``substep_control`` are the implementation it calls: the kernels of
    :mod:`.controller_kernels` (or, in the tests, their numpy references of the same signatures)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, index: WorldIndex, bodies: list[CharacterBody],
                 params: TrackerParams, frame_terms: Callable, substep_control: Callable) -> None:
        self.model, self.data = model, data
        g = params.gains
        n, b = len(index.pt_body), len(index.b_body)
        self.force_bound = np.ascontiguousarray(force_bounds(bodies, index, params), dtype=np.float64)
        self.scale_body = twist_inertia(model, index)
        self._kp = np.full(n, float(g.kp))   # Eq 1 gains per point, N/m and N·s/m
        self._kd = np.full(n, float(g.kd))
        self._gains = (float(g.kp_rot), float(g.kd_rot), float(g.max_torque))
        d = data   # views into mjData (mj_resetData keeps its buffers)
        self.sim = tuple(ck.Sim(d.site_xpos, d.cvel, d.subtree_com, d.xipos, d.xquat, d.xmat, d.xfrc_applied))
        self.points = tuple(ck.Points(index.pt_site, index.pt_body, index.pt_root, self.force_bound))
        self.bodies = tuple(ck.Bodies(index.b_body, index.b_axis, self.scale_body))
        self.terms = tuple(ck.Terms(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n)))
        self._f, self._tq, self._tops = np.zeros((n, 3)), np.zeros((b, 3)), np.zeros(2)
        self._frame_terms, self._substep = frame_terms, substep_control
        self.last_forces = np.zeros((n, 3))     # N, each point's Eq 1 force in the last substep
        self.last_torques = np.zeros((b, 3))    # N·m, each body's Eq 2 torque in the last frame
        self.max_applied_force = 0.0            # N, largest Eq 1 force ever applied
        self.max_applied_torque = 0.0           # N·m, largest Eq 2 torque ever applied

    def run(self, n: int, targets: tuple, rotations: tuple, extra: Callable[[], None] | None,
            profile: dict[str, float] | None) -> None:
        """``n`` substeps tracking ``targets`` and ``rotations`` (the tuples of
        :class:`~.controller_kernels.Targets` and ``Orientations``); ``extra()`` adds the props'
        forces to ``xfrc_applied`` after the control of each substep."""
        m, d = self.model, self.data
        ts = m.opt.timestep
        t = time.thread_time() if profile is not None else 0.0
        self._frame_terms(targets, self._kp, self._kd, n * ts, ts, self.terms)
        f, tq, tops = self._f, self._tq, self._tops
        fmax2 = 0.0
        for i in range(n):
            if profile is not None:
                t = tick(profile, "controller", t)
            mujoco.mj_step1(m, d)
            if profile is not None:
                t = tick(profile, "mj_step", t)
            self._substep(self.sim, self.points, self.bodies, self.terms, rotations, self._gains, i, f, tq, tops)
            fmax2 = max(fmax2, tops[0])
            if extra is not None:
                extra()
            if profile is not None:
                t = tick(profile, "controller", t)
            mujoco.mj_step2(m, d)
            if profile is not None:
                t = tick(profile, "mj_step", t)
        self.max_applied_force = max(self.max_applied_force, math.sqrt(fmax2))
        self.max_applied_torque = max(self.max_applied_torque, float(tops[1]))
        self.last_forces, self.last_torques = f.copy(), tq.copy()   # the kernels' buffers change next step
