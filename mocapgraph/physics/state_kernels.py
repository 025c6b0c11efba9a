"""Compiled per-frame state read-out of the physics world: published geom poses and errors, the
simulated character's local rotations.

Numpy references: :mod:`.reference` (the same signatures; tests compare them). Reads MuJoCo's
``mjData`` arrays in place; m, wxyz (w >= 0 for geoms, as ``kinematics.quaternion.matrix_to_quat``),
world frame Z up.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import kernel_calling
from ..kinematics import quat_kernels

kernel = kernel_calling(quat_kernels)   # matrix_to_quat_into, qmul


class GeomLayout(NamedTuple):
    """What the published geoms read (passed as ``tuple(layout)``, see :mod:`.controller_kernels`)."""

    geom_ids: np.ndarray    # [G] published geoms (every one but the floor)
    pt_site: np.ndarray     # [N] the site of each stacked joint point
    geom_j0: np.ndarray     # [G] a character capsule's two joints (stacked points), -1: not one
    geom_j1: np.ndarray     # [G]
    point_err: np.ndarray   # [N] m, scratch: each joint's distance to its target (written)


@kernel
def geom_state_into(geom_xpos, geom_xmat, site_xpos, lay, p_t, override, pos, quat, err) -> None:
    """Published geoms ``geom_ids`` [G]: positions ``pos`` [G, 3], orientations ``quat`` [G, 4]
    (Shepperd's method from ``geom_xmat``, w >= 0), and ``err`` [G] the mean tracking error of a
    character capsule's two joints (``geom_j0/1``, -1: not a capsule, NaN). ``point_err`` [N] gets
    each joint's distance to its target (the override where one is set; NaN without target)."""
    geom_ids, pt_site, geom_j0, geom_j1, point_err = lay
    for i in range(pt_site.shape[0]):
        s = pt_site[i]
        e2 = 0.0
        for c in range(3):
            t = override[i, c] if math.isfinite(override[i, c]) else p_t[i, c]
            d = site_xpos[s, c] - t
            e2 += d * d
        point_err[i] = math.sqrt(e2)
    for i in range(geom_ids.shape[0]):
        g = geom_ids[i]
        pos[i, 0], pos[i, 1], pos[i, 2] = geom_xpos[g, 0], geom_xpos[g, 1], geom_xpos[g, 2]
        m00, m01, m02 = geom_xmat[g, 0], geom_xmat[g, 1], geom_xmat[g, 2]
        m10, m11, m12 = geom_xmat[g, 3], geom_xmat[g, 4], geom_xmat[g, 5]
        m20, m21, m22 = geom_xmat[g, 6], geom_xmat[g, 7], geom_xmat[g, 8]
        quat_kernels.matrix_to_quat_into(m00, m01, m02, m10, m11, m12, m20, m21, m22, quat, i)
        if geom_j0[i] >= 0:
            err[i] = 0.5 * (point_err[geom_j0[i]] + point_err[geom_j1[i]])
        else:
            err[i] = np.nan


@kernel
def local_rotations_into(qpos, ball_adr, ball_joints, root_adr, root_joint, rest_root, out, root_pos) -> None:
    """One simulated character's local rotations into ``out`` [J, 4] (rows not set by a body keep
    what they hold, e.g. their target's): each ball joint's ``qpos`` quaternion, the root's free
    joint quaternion with the rest rotation taken off (``conj(rest_root) q``); every row
    normalised. ``root_pos`` [3] gets the root's position, m."""
    for i in range(ball_adr.shape[0]):
        a = ball_adr[i]
        j = ball_joints[i]
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = qpos[a], qpos[a + 1], qpos[a + 2], qpos[a + 3]
    r = root_adr
    root_pos[0], root_pos[1], root_pos[2] = qpos[r], qpos[r + 1], qpos[r + 2]
    aw, ax, ay, az = rest_root[0], -rest_root[1], -rest_root[2], -rest_root[3]
    bw, bx, by, bz = qpos[r + 3], qpos[r + 4], qpos[r + 5], qpos[r + 6]
    j = root_joint
    out[j, 0], out[j, 1], out[j, 2], out[j, 3] = quat_kernels.qmul(aw, ax, ay, az, bw, bx, by, bz)
    for j in range(out.shape[0]):
        n = math.sqrt(out[j, 0] * out[j, 0] + out[j, 1] * out[j, 1] + out[j, 2] * out[j, 2] + out[j, 3] * out[j, 3])
        for c in range(4):
            out[j, c] /= n


def warm() -> None:
    """Compile every kernel here once on small inputs (fills the on-disk cache)."""
    n, g = 2, 2
    idx = np.arange(n, dtype=np.int64)
    xm = np.tile(np.eye(3).ravel(), (g, 1))
    lay = tuple(GeomLayout(idx, idx, idx, idx, np.zeros(n)))
    geom_state_into(np.zeros((g, 3)), xm, np.zeros((n, 3)), lay, np.zeros((n, 3)), np.full((n, 3), np.nan),
                    np.zeros((g, 3)), np.zeros((g, 4)), np.zeros(g))
    qpos = np.zeros(11)
    qpos[3] = qpos[7] = 1.0
    local_rotations_into(qpos, np.array([7], dtype=np.int64), np.array([1], dtype=np.int64), 0, 0,
                         np.array([1.0, 0, 0, 0]), np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros(3))
