"""The stage's props and their behaviours in a physics world: pushes, the ball shooter, the dodge, reach.

* :class:`Pushes`: external forces (N, world) at a joint for a span of simulated time, added to
  ``xfrc_applied`` after the bounded control of every substep;
* :class:`BallShooter`: the stage shooter's pool of balls, shot on ballistic arcs and parked;
* :class:`Dodge`: Shum & Ho's Figure 4, forearm targets raised around the head while a ball comes
  at it (set as the targets' ``dodge_override`` for the frame);
* :func:`reach_point`: the point of a stage geom's surface nearest to a joint's target, where
  ``reach`` puts the hand (a positional constraint).

World frame Z up, X forward; SI units.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .index import WorldIndex
from .stage import PARK_X, Stage

GRAVITY = np.array([0.0, 0.0, -9.81])


@dataclass
class _Push:
    point: int          # index into the stacked points
    force: np.ndarray   # N, world
    until: float        # sim time, s


class Pushes:
    """Pushes in progress."""

    def __init__(self, data: mujoco.MjData, index: WorldIndex) -> None:
        self.data, self.index = data, index
        self.active: list[_Push] = []

    def add(self, point: int, force: np.ndarray, duration_s: float) -> None:
        """Push stacked point ``point`` with ``force`` (N, world: 3 finite numbers) for ``duration_s`` s."""
        f = np.asarray(force, float)
        if f.shape != (3,) or not np.isfinite(f).all() or not np.isfinite(duration_s) or duration_s < 0:
            raise ValueError(f"push: force {force!r} must be 3 finite numbers, duration >= 0")
        self.active.append(_Push(point, f, self.data.time + duration_s))

    def apply(self) -> None:
        """Active pushes added to ``xfrc_applied`` at their points (force and its moment about the CoM)."""
        d, ix = self.data, self.index
        for push in self.active:
            if d.time < push.until:
                b = ix.pt_body[push.point]
                arm = d.site_xpos[ix.pt_site[push.point]] - d.xipos[b]
                d.xfrc_applied[b, :3] += push.force
                d.xfrc_applied[b, 3:] += np.cross(arm, push.force)

    def expire(self) -> None:
        """Forget the pushes whose time is over."""
        if self.active:
            self.active = [p for p in self.active if self.data.time < p.until]


class BallShooter:
    """The stage shooter's balls (none without a shooter)."""

    def __init__(self, data: mujoco.MjData, index: WorldIndex, stage: Stage) -> None:
        self.data, self.index, self.stage = data, index, stage
        self._next = 0

    def shoot(self, target: np.ndarray, speed: float | None = None, origin: np.ndarray | None = None) -> int:
        """Shoot the next ball at ``target`` (world m) on a ballistic arc at ``speed`` m/s from
        ``origin`` (the shooter's when None); returns the ball's number."""
        sh = self.stage.shooter
        if sh is None:
            raise ValueError("this stage has no ball shooter")
        k = self._next
        self._next = (k + 1) % sh.pool
        o = sh.origin if origin is None else np.asarray(origin, float)
        target = np.asarray(target, float)
        s = sh.speed if speed is None else float(speed)
        T = np.linalg.norm(target - o) / s
        v = (target - o) / T - 0.5 * GRAVITY * T
        a, dv = self.index.ball_joint[k], self.index.ball_dof[k]
        d = self.data
        d.qpos[a:a + 3] = o
        d.qpos[a + 3:a + 7] = (1, 0, 0, 0)
        d.qvel[dv:dv + 3] = v
        d.qvel[dv + 3:dv + 6] = 0
        return k

    def park(self) -> None:
        """Every ball back to its parking place, at rest."""
        for k, (a, dv) in enumerate(zip(self.index.ball_joint, self.index.ball_dof)):
            self.data.qpos[a:a + 7] = (PARK_X + 0.5 * k, 0, self.stage.shooter.radius, 1, 0, 0, 0)
            self.data.qvel[dv:dv + 6] = 0


class Dodge:
    """Figure 4: each character raises its forearms around its head while a ball comes at it."""

    def __init__(self, data: mujoco.MjData, index: WorldIndex, joint_names: list[tuple[str, ...]],
                 horizon_s: float) -> None:
        self.data, self.index, self.horizon_s = data, index, horizon_s
        self.joint_names = joint_names
        self._until = np.full(len(joint_names), -np.inf)
        self._dir = np.zeros(3)
        self.dodging = False   # dodge targets set this frame

    def update(self, on: bool, dodge_override: np.ndarray) -> bool:
        """This frame's forearm targets into ``dodge_override`` [N, 3] (cleared first when the last
        frame set some); True while any is set."""
        if self.dodging:
            dodge_override[:] = np.nan
            self.dodging = False
        ix = self.index
        if not on or not len(ix.ball_body):
            return False
        d = self.data
        bp = d.xpos[ix.ball_body]
        bv = np.array([d.qvel[a:a + 3] for a in ix.ball_dof])
        moving = np.linalg.norm(bv, axis=1) > 1.0
        for k, names in enumerate(self.joint_names):
            if "Head" not in names:
                continue
            hp = d.site_xpos[ix.pt_site[ix.point(k, names.index("Head"))]]
            rel = hp - bp
            speed2 = np.maximum((bv * bv).sum(1), 1e-9)
            t_close = (rel * bv).sum(1) / speed2
            miss = np.linalg.norm(rel - bv * t_close[:, None], axis=1)
            threat = moving & (t_close > 0) & (t_close < self.horizon_s) & (miss < 0.35)
            if threat.any():
                self._until[k] = d.time + 0.4
                i = int(np.flatnonzero(threat)[np.argmin(t_close[threat])])
                self._dir = -bv[i] / np.linalg.norm(bv[i])
            if d.time < self._until[k]:
                self._raise_forearms(k, hp, self._dir, dodge_override)
                self.dodging = True
        return self.dodging

    def _raise_forearms(self, k: int, head: np.ndarray, towards: np.ndarray, out: np.ndarray) -> None:
        """Forearm targets (elbows, wrists, hands) set around the head, facing the ball."""
        names = self.joint_names[k]
        front = towards.copy()
        front[2] = 0.0
        front /= max(np.linalg.norm(front), 1e-9)
        up = np.array([0.0, 0, 1])
        left = np.cross(up, front)
        for side, s in (("Left", 1.0), ("Right", -1.0)):
            spots = {f"Elbow{side}": head + 0.12 * front + s * 0.22 * left - 0.05 * up,
                     f"Wrist{side}": head + 0.22 * front + s * 0.07 * left + 0.06 * up,
                     f"Hand{side}": head + 0.24 * front + s * 0.03 * left + 0.14 * up}
            for jn, p in spots.items():
                if jn in names:
                    out[self.index.point(k, names.index(jn))] = p


def reach_point(model: mujoco.MjModel, data: mujoco.MjData, geom: str, base: np.ndarray) -> np.ndarray:
    """The point (world m) of stage geom ``geom``'s surface nearest to ``base``: a box's through
    its nearest face when ``base`` is inside, else along the line from a round geom's centre."""
    g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, geom)
    if g < 0:
        raise KeyError(f"no stage geom {geom!r}")
    c = data.geom_xpos[g]
    R = data.geom_xmat[g].reshape(3, 3)
    size = model.geom_size[g]
    if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
        loc = np.clip(R.T @ (base - c), -size, size)
        if (np.abs(loc) < size).all():  # inside: out through the nearest face
            ax = int(np.argmin(size - np.abs(loc)))
            loc[ax] = np.copysign(size[ax], loc[ax])
        return c + R @ loc
    d = base - c
    return c + d / max(np.linalg.norm(d), 1e-9) * size[0]
