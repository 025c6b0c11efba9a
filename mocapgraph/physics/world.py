"""One MuJoCo world of characters tracking target poses on a stage (Shum & Ho, sections 4 and 6), composed of parts.

In the spirit of dm_control's composer, :class:`PhysicsWorld` only composes and sequences:

* the model: :func:`.mjcf.build_model` (MJCF of the floor, characters, pins, stage, welds);
* the index of names to ids: :class:`.index.WorldIndex`;
* the targets and positional constraints: :class:`.targets.TargetState`;
* the controller (Eq 1 forces at every joint, Eq 2 twist torques on every body, bounded):
  :class:`.control.Controller`;
* the constraints: :class:`.constraints.FootPins` (virtual joints, 6.1) and :class:`.constraints.HeldObjects`;
* the stage's props and behaviours: :mod:`.props` (pushes, the ball shooter, the dodge, reach);
* the read-out: :class:`.readout.Readout`.

Per input frame: :meth:`PhysicsWorld.set_target` takes each character's target joint positions
``P_e`` and world joint orientations (``Θ_e``), both world frame (m, wxyz); :meth:`step` switches
the pins, sets the dodge's targets and advances the frame's span in substeps of ``timestep`` (the
controller's), then recovers a state that blew up. The per-frame arithmetic is one implementation,
:data:`COMPILED` (numba kernels); the tests build worlds on :data:`.reference.REFERENCE` (their numpy
references, the same signatures) and compare the two. Frames: world Z up, X forward; SI units.
"""
from __future__ import annotations

import math
import time
from typing import Callable, NamedTuple

import mujoco
import numpy as np

from ..retarget.character import Character
from ..kinematics.quaternion import quat_multiply
from . import controller_kernels as ck
from . import state_kernels as sk
from .body import character_body
from .constraints import FootPins, HeldObjects
from .control import Controller, tick
from .index import index_world
from .mjcf import build_model
from .params import TrackerParams
from .props import BallShooter, Dodge, Pushes, reach_point
from .readout import Readout
from .stage import EMPTY_STAGE, Stage
from .targets import TargetState

__all__ = ["COMPILED", "Kernels", "PhysicsWorld", "TrackerParams"]


class Kernels(NamedTuple):
    """The per-frame implementation the parts call (kernels, or numpy references of the same signatures)."""

    frame_terms: Callable
    substep_control: Callable
    set_target_into: Callable
    switch_pins: Callable
    geom_state_into: Callable
    local_rotations_into: Callable


COMPILED = Kernels(ck.frame_terms, ck.substep_control, ck.set_target_into, ck.switch_pins, sk.geom_state_into,
                   sk.local_rotations_into)
_BAD = (int(mujoco.mjtWarning.mjWARN_BADQACC), int(mujoco.mjtWarning.mjWARN_BADQVEL),
        int(mujoco.mjtWarning.mjWARN_BADQPOS))


class PhysicsWorld:
    """Characters and a stage in one MuJoCo world, each character tracking its own target."""

    def __init__(self, characters: list[Character], stage: Stage = EMPTY_STAGE,
                 params: TrackerParams | None = None, spawns: list | None = None,
                 kernels: Kernels = COMPILED) -> None:
        self.params = params or TrackerParams()
        self.params.gains.check()
        if not characters:
            raise ValueError("a physics world needs at least one character")
        if spawns is None:
            spawns = [np.array([0.0, 1.5 * k, 0.0]) for k in range(len(characters))]
        self.stage = stage
        self.bodies = [character_body(c, k, self.params.body_mass, spawns[k]) for k, c in enumerate(characters)]
        self.xml, self.model = build_model(self.bodies, stage, self.params)
        self.data = mujoco.MjData(self.model)
        m, d, prm = self.model, self.data, self.params
        self.index = ix = index_world(m, self.bodies, stage)
        self.targets = TargetState(ix, kernels.set_target_into, prm.max_target_speed)
        self.control = Controller(m, d, ix, self.bodies, prm, kernels.frame_terms, kernels.substep_control)
        self.pins = FootPins(d, ix, prm, kernels.switch_pins)
        self.held = HeldObjects(m, d, stage, len(self.bodies))
        self.pushes = Pushes(d, ix)
        self.shooter = BallShooter(d, ix, stage)
        self.dodge = Dodge(d, ix, [cb.character.joint_names for cb in self.bodies], prm.dodge_horizon_s)
        self.readout = Readout(m, d, ix, self.bodies, kernels.geom_state_into, kernels.local_rotations_into)
        self.frames_stepped = 0
        self.resets = 0                  # times the state went non-finite and was reset to the target
        self.profile: dict[str, float] | None = None   # set to {} to sum CPU s per stage of step()
        self._warnings = d.warning.number   # views into mjData (mj_resetData keeps its buffers)
        self._qvel = d.qvel
        self._badqacc = 0
        mujoco.mj_forward(m, d)

    # ----- targets -----------------------------------------------------------------------------
    def set_pose(self, k: int, local_rotations: np.ndarray, root_position: np.ndarray) -> None:
        """Put character ``k`` exactly in a pose (local rotations wxyz [J,4], root m), at rest, raised
        onto the floor when a capsule would reach into it."""
        cb = self.bodies[k]
        ch = cb.character
        adr = self.index.qpos_adr[k]
        q = self.data.qpos
        loc = np.asarray(local_rotations, float)
        for b, j in enumerate(cb.body_joints):
            a = adr[b]
            if j == ch.root:
                q[a:a + 3] = root_position
                q[a + 3:a + 7] = quat_multiply(ch.rest_rotations[j], loc[j])
            else:
                q[a:a + 4] = loc[j]
        mine = self.index.b_body[self.index.body_slice[k]]
        for a, n in zip(self.model.body_dofadr[mine], self.model.body_dofnum[mine]):
            self.data.qvel[a:a + n] = 0.0
        mujoco.mj_forward(self.model, self.data)
        # a pose reaching into the floor (a heel strike cutting it, a source whose floor is not
        # ours) is raised onto it: a body started 5 cm or more deep blows MuJoCo's contact solver
        # up on its first step (and the node's reset put it back there, again and again)
        low = self.readout.lowest_point(k)
        if low < 0.0:
            r = adr[int(np.flatnonzero(cb.body_joints == ch.root)[0])]
            q[r + 2] -= low
            mujoco.mj_forward(self.model, self.data)
        self.held.snap()
        self.pins.release(k)

    def set_target(self, k: int, positions: np.ndarray, orientations: np.ndarray, time_s: float) -> None:
        """Target of character ``k``: joint positions [J, 3] m and world joint orientations [J, 4]
        wxyz (NaN rows: no target for that joint), at input time ``time_s`` (for the velocities)."""
        self.targets.set(k, positions, orientations, time_s)

    def _point(self, k: int, joint: int | str) -> int:
        j = self.bodies[k].character.index(joint) if isinstance(joint, str) else int(joint)
        return self.index.point(k, j)

    def set_override(self, k: int, joint: int | str, position: np.ndarray | None) -> None:
        """Positional constraint: joint ``joint`` of character ``k`` targets ``position`` (world m)
        instead of its input target, until set to None."""
        self.targets.set_override(self._point(k, joint), position)

    def reach(self, k: int, joint: int | str, geom: str) -> np.ndarray:
        """Move joint ``joint``'s target onto the surface of stage geom ``geom`` (the surface point
        nearest to the joint's current target) and return that point."""
        i = self._point(k, joint)
        t = self.targets.p_t[i]
        base = t if np.isfinite(t).all() else self.readout.point_positions()[i]
        point = reach_point(self.model, self.data, geom, base)
        self.targets.set_override(i, point)
        return point

    # ----- interaction -------------------------------------------------------------------------
    def push(self, k: int, joint: int | str, force: np.ndarray, duration_s: float) -> None:
        """An external push (N, world) at joint ``joint`` of character ``k`` for ``duration_s``."""
        self.pushes.add(self._point(k, joint), force, duration_s)

    def shoot(self, target: np.ndarray, speed: float | None = None, origin: np.ndarray | None = None) -> int:
        """Shoot the next ball of the stage's shooter at ``target`` (world m); returns its number."""
        return self.shooter.shoot(target, speed, origin)

    def park_balls(self) -> None:
        self.shooter.park()

    def set_held(self, on: bool) -> None:
        """Hold (weld) or drop every held object."""
        self.held.set(on)

    # ----- stepping ----------------------------------------------------------------------------
    def step(self, duration_s: float) -> None:
        """Advance by ``duration_s`` (rounded to whole substeps, at least one)."""
        ts = self.model.opt.timestep
        n = max(1, int(round(duration_s / ts)))
        prof = self.profile
        t = time.thread_time() if prof is not None else 0.0
        tg = self.targets
        self.pins.update(tg.inputs, n * ts)
        self.dodge.update(self.params.dodge, tg.dodge_override)
        if prof is not None:
            t = tick(prof, "pins, dodge", t)
        self.control.run(n, tg.points, tg.rotations, self.pushes.apply if self.pushes.active else None, prof)
        if prof is not None:
            t = time.thread_time()
        self.pushes.expire()
        self.frames_stepped += 1
        wn, (a, b, c) = self._warnings, _BAD
        if int(wn[a]) + int(wn[b]) + int(wn[c]) > self._badqacc or not math.isfinite(self._qvel.sum()):
            self._recover()
        if prof is not None:
            tick(prof, "checks", t)

    def _recover(self) -> None:
        """The state blew up (MuJoCo reset it or it went NaN): put each character on its target."""
        self.resets += 1
        keep = self.data.warning.number.copy()
        now = float(self.data.time)
        self._badqacc = int(keep[list(_BAD)].sum())
        mujoco.mj_resetData(self.model, self.data)
        self.data.warning.number[:] = keep
        self.data.time = now   # the clock goes on (pushes, the dodge and the node's status run on it)
        mujoco.mj_forward(self.model, self.data)

    # ----- outputs -----------------------------------------------------------------------------
    def geom_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Published geoms: positions [G, 3] m, orientations [G, 4] wxyz, tracking error [G] m."""
        return self.readout.geom_state(self.targets.p_t, self.targets.override)

    def tracking_error(self) -> np.ndarray:
        """Per stacked joint: distance from the simulated joint to its target, m (NaN: no target)."""
        return self.readout.tracking_error(self.targets.p_t, self.targets.override)

    def geom_shapes(self) -> tuple[tuple[str, ...], np.ndarray]:
        return self.readout.geom_shapes()

    def joint_positions(self, k: int) -> np.ndarray:
        return self.readout.joint_positions(k)

    def local_rotations(self, k: int, leaf_rotations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        return self.readout.local_rotations(k, leaf_rotations)

    def lowest_point(self, k: int) -> float:
        return self.readout.lowest_point(k)
