"""Shum & Ho's section-6 controller: bounded PD forces at joints (Eq 1) and twist torques (Eq 2).

Pure numpy on stacked arrays (every controlled point and body of every character at once):

* Eq 1, per joint: ``F = Ke (p_target - p) + Kd (v_target - v)``, its norm clipped to ``max_force``;
* Eq 2, per body: ``T = (Ke_rot theta + Kd_rot (w_target - w) . a) a`` about the body's bone axis
  ``a`` (the "rotation along the joint axis"), ``theta`` the twist of the target orientation
  relative to the current one about ``a``; ``|T|`` clipped to ``max_torque``.

Units: m, m/s, N, N·m, rad. Gains are one pair for all joints (the paper's), each optionally scaled
per joint/body (``scale``; the world scales Eq 2 by each body's inertia about its axis). A point or body with a non-finite target gets no force.
"""
from __future__ import annotations

from dataclasses import dataclass

import math

import numpy as np

from ..kinematics.quaternion import quat_multiply_conj_rows


@dataclass
class Gains:
    """Controller gains and bounds (SI)."""

    kp: float = 2500.0        # Ke, N/m
    kd: float = 60.0          # Kd, N·s/m
    kp_rot: float = 400.0     # K_epsilon per unit inertia about the axis, 1/s^2 (N·m/rad per kg·m^2)
    kd_rot: float = 40.0      # K_delta per unit inertia, 1/s
    max_force: float = 400.0  # N, per joint
    max_torque: float = 60.0  # N·m, per body

    def check(self) -> "Gains":
        for k, v in self.__dict__.items():
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"gains: {k} = {v} must be a finite number >= 0")
        return self


def _cross_table() -> np.ndarray:
    t = np.zeros((3, 3, 3))
    for i, j, k in ((1, 2, 0), (2, 0, 1), (0, 1, 2)):
        t[i, j, k], t[j, i, k] = 1.0, -1.0
    return t.reshape(9, 3)


_CROSS = _cross_table()  # component k of a x b = sum over (i, j) of table * a_i b_j


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of [N, 3] arrays, as one outer product and one matmul (np.cross costs ~30 us
    a call in its axis handling; column arithmetic ~10 small operations). Exact: each component is
    two products and zeros."""
    ab = a[..., :, None] * b[..., None, :]
    return ab.reshape(ab.shape[:-2] + (9,)) @ _CROSS


def clip_norm(v: np.ndarray, limit: float | np.ndarray) -> np.ndarray:
    """Rows of ``v`` scaled down so that none is longer than ``limit``."""
    n = np.sqrt((v * v).sum(-1, keepdims=True))
    lim = np.asarray(limit, dtype=np.float64)
    if lim.ndim:
        lim = lim[:, None]
    scale = np.minimum(1.0, lim / np.maximum(n, 1e-12))
    return v * scale


def joint_forces(g: Gains, p: np.ndarray, v: np.ndarray, p_t: np.ndarray, v_t: np.ndarray,
                 scale: np.ndarray | None = None) -> np.ndarray:
    """Eq 1 for every point [N, 3] (world, m and m/s) -> forces [N, 3] N, bounded, 0 where no target."""
    kp = g.kp if scale is None else g.kp * scale[:, None]
    kd = g.kd if scale is None else g.kd * scale[:, None]
    f = kp * (p_t - p) + kd * (v_t - v)
    f = np.where(np.isfinite(f), f, 0.0)
    return clip_norm(f, g.max_force)


def twist_angle(q_t: np.ndarray, q: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Twist (rad, in (-pi, pi]) about world ``axis`` [N, 3] of the rotation taking ``q`` to ``q_t``
    (wxyz [N, 4]): the twist part of the swing-twist decomposition of ``q_t q^-1``."""
    e = quat_multiply_conj_rows(q_t, q)
    ew = e[:, 0]
    s = (e[:, 1:] * axis).sum(1)
    sign = np.copysign(1.0, ew)  # q and -q are one rotation: take the short way round
    return 2.0 * np.arctan2(s * sign, ew * sign)


def twist_torques(g: Gains, q: np.ndarray, w: np.ndarray, axis: np.ndarray, q_t: np.ndarray,
                  w_t: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """Eq 2 for every body: orientations wxyz [N, 4], angular velocities [N, 3] rad/s (world),
    world twist axes [N, 3] unit -> torques [N, 3] N·m along the axes, bounded, 0 without target."""
    theta = twist_angle(q_t, q, axis)
    rate = ((w_t - w) * axis).sum(1)
    kp = g.kp_rot if scale is None else g.kp_rot * scale
    kd = g.kd_rot if scale is None else g.kd_rot * scale
    t = np.minimum(np.maximum(kp * theta + kd * rate, -g.max_torque), g.max_torque)
    if not math.isfinite(t.sum()):
        t = np.where(np.isfinite(t), t, 0.0)
    return t[:, None] * axis
