"""The constraints of a physics world: foot pins (Shum & Ho 6.1's virtual joints) and held objects.

A foot pin is a MuJoCo ``connect`` constraint between a foot point and a mocap body: switched on
where the foot's input target is on the floor and still, placed where the simulated foot is, drawn
after a target that drifts from it at a bounded horizontal speed (a pivoting foot), and off when the
target lifts, speeds up or jumps away (the rule is :func:`.controller_kernels.switch_pins`'s
docstring). A held object is a ``weld`` to the hand's body, snapped into the hand whenever it is
switched on or the body is put in a pose. World frame Z up, m.
"""
from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

from ..kinematics.quaternion import quat_conjugate, quat_multiply
from . import controller_kernels as ck
from .index import WorldIndex
from .params import TrackerParams
from .stage import Stage


class FootPins:
    """Every character's foot pins; ``on`` [P] says which hold now."""

    def __init__(self, data: mujoco.MjData, index: WorldIndex, params: TrackerParams, switch_pins: Callable) -> None:
        self.data, self.params = data, params
        self.index = index
        self.eq, self.mocap, self.point = index.pin_eq, index.pin_mocap, index.pin_point
        self.rest_z = index.pin_rest_z
        self.on = np.zeros(len(self.eq), dtype=bool)
        self.char = index.pin_char
        self._pins = tuple(ck.Pins(self.point, self.rest_z, self.on, self.mocap, self.eq))
        self._switch = switch_pins

    def update(self, inputs: tuple, span: float) -> None:
        """Switch the pins for a frame of ``span`` s by the input targets (the tuple of
        :class:`~.controller_kernels.Inputs`) and draw pinned ones after their targets."""
        if not len(self.eq):
            return
        prm, d = self.params, self.data
        if not prm.virtual_joints:
            if self.on.any():
                self.on[:] = False
                d.eq_active[self.eq] = 0
            return
        rule = (float(prm.contact_height), float(prm.contact_speed), float(prm.pin_slack), float(prm.pin_hold),
                float(prm.pin_follow_speed * span))
        self._switch(inputs, self._pins, d.mocap_pos, d.site_xpos, self.index.pt_site, d.eq_active, rule)

    def release(self, k: int) -> None:
        """Character ``k``'s pins off (it was put in a pose)."""
        mine = self.char == k
        self.on[mine] = False
        self.data.eq_active[self.eq[mine]] = 0


class HeldObjects:
    """The stage's objects held in a hand (``held_by``), welded while held."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, stage: Stage, n_characters: int) -> None:
        self.model, self.data = model, data
        self.held = []  # (eq id, object body id, hand body id, object pose in the hand frame)
        d0 = mujoco.MjData(model)
        mujoco.mj_forward(model, d0)  # the model's own pose: where each weld is satisfied
        for o in stage.objects:
            if o.held_by is not None and o.held_by[0] < n_characters:
                eq = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, f"hold/{o.name}")
                obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"stage/{o.name}")
                hand = int(model.eq_obj1id[eq])
                Rh = d0.xmat[hand].reshape(3, 3)
                rel_p = Rh.T @ (d0.xpos[obj] - d0.xpos[hand])
                rel_q = quat_multiply(quat_conjugate(d0.xquat[hand]), d0.xquat[obj])
                self.held.append((eq, obj, hand, rel_p, rel_q))

    def set(self, on: bool) -> None:
        """Hold (weld) or drop every held object."""
        for eq, *_ in self.held:
            if on and not self.data.eq_active[eq]:
                self.snap()
            self.data.eq_active[eq] = int(on)

    def snap(self) -> None:
        """Put each held object where its weld wants it relative to the hand (no jump on start)."""
        m, d = self.model, self.data
        for eq, obj, hand, rel_p, rel_q in self.held:
            a = m.jnt_qposadr[m.body_jntadr[obj]]
            dv = m.jnt_dofadr[m.body_jntadr[obj]]
            d.qpos[a:a + 3] = d.xpos[hand] + d.xmat[hand].reshape(3, 3) @ rel_p
            d.qpos[a + 3:a + 7] = quat_multiply(d.xquat[hand], rel_q)
            d.qvel[dv:dv + 6] = 0
        if self.held:
            mujoco.mj_forward(m, d)
