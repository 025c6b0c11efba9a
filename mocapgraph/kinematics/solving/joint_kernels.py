"""Compiled kernel of a live frame's joint centres from its limb poses (every limb seen, fit well).

The same arithmetic as :meth:`mocapgraph.kinematics.solving.solver.FrameSolver._joints_from_limbs` on
its common live frame (its numpy code is the reference the tests compare this to): each joint
seen from each attached limb (``R p + t``, m, world), the inverse-variance weighted mean of the
estimates, then bone lengths enforced outward from the root. Float64 / int64 arrays, outputs
preallocated by the caller.
"""
from __future__ import annotations

import numpy as np

from mocapgraph.jit import kernel


def joint_model(lab: np.ndarray, pt: np.ndarray, has: np.ndarray, var_static: np.ndarray, sig2_lab: np.ndarray,
                rms_tol: np.ndarray, child: np.ndarray, parent: np.ndarray, length: np.ndarray) -> tuple:
    """A calibrated model's constants for `joints_all_seen`, as one plain tuple (numba's dispatcher
    types a plain tuple in C, a named tuple in Python: ~0.5 us more per field, a call).

    Estimate e (2J of them: column j from joint j's proximal limb, J + j from its distal one) is
    limb lab[e]'s point pt[e] (base pose, m), counted where has[e], with variance factors
    var_static[e] and sig2_lab[e] (m^2); rms_tol[L] (m) is the worst limb fit the kernel takes;
    child[k], parent[k], length[k] (m) are the bones enforced, in order outward from the root."""
    i8 = lambda v: np.ascontiguousarray(v, dtype=np.int64)    # noqa: E731
    f8 = lambda v: np.ascontiguousarray(v, dtype=float)       # noqa: E731
    return (i8(lab), f8(pt), i8(has), f8(var_static), f8(sig2_lab), f8(rms_tol), i8(child), i8(parent), f8(length))


@kernel
def joints_all_seen(rot: np.ndarray, trans: np.ndarray, nfit: np.ndarray, rms: np.ndarray, model: tuple,
                    joints: np.ndarray) -> bool:
    """joints[J,3] from limb poses rot[L,3,3], trans[L,3] (``x = R x_ref + t``), their fits'
    marker counts nfit[L] and residuals rms[L] (m); ``model`` from `joint_model`.

    Estimate e's variance is (sig2_lab[e] + rms[lab]^2) var_static[e] / max(nfit[lab], 1). Then,
    in order, each child joint is moved along its bone to ``length`` (m) from its parent. False,
    with nothing done, if a limb fit is worse than rms_tol[L] (m), or if a joint came out
    non-finite: the caller then takes the general path.
    """
    lab, pt, has, var_static, sig2_lab, rms_tol, child, parent, length = model   # see joint_model
    J = joints.shape[0]
    for l in range(rms.size):
        if not rms[l] <= rms_tol[l]:
            return False
    for j in range(J):
        sw = s0 = s1 = s2 = 0.0
        for side in range(2):
            e = side * J + j
            if not has[e]:
                continue
            l = lab[e]
            n = nfit[l] if nfit[l] > 1 else 1
            w = 1.0 / ((sig2_lab[e] + rms[l] * rms[l]) * (var_static[e] / n))
            p0, p1, p2 = pt[e, 0], pt[e, 1], pt[e, 2]
            s0 += w * (rot[l, 0, 0] * p0 + rot[l, 0, 1] * p1 + rot[l, 0, 2] * p2 + trans[l, 0])
            s1 += w * (rot[l, 1, 0] * p0 + rot[l, 1, 1] * p1 + rot[l, 1, 2] * p2 + trans[l, 1])
            s2 += w * (rot[l, 2, 0] * p0 + rot[l, 2, 1] * p1 + rot[l, 2, 2] * p2 + trans[l, 2])
            sw += w
        joints[j, 0], joints[j, 1], joints[j, 2] = s0 / sw, s1 / sw, s2 / sw
        if not (np.isfinite(joints[j, 0]) and np.isfinite(joints[j, 1]) and np.isfinite(joints[j, 2])):
            return False
    for k in range(child.size):
        c, p = child[k], parent[k]
        v0, v1, v2 = joints[c, 0] - joints[p, 0], joints[c, 1] - joints[p, 1], joints[c, 2] - joints[p, 2]
        d = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        # Coincident joints (d = 0) stay put, as in the numpy path.
        s = length[k] / (d if d > 1e-9 else 1e-9)
        joints[c, 0] = joints[p, 0] + v0 * s
        joints[c, 1] = joints[p, 1] + v1 * s
        joints[c, 2] = joints[p, 2] + v2 * s
    return True


def warm() -> None:
    """Compile the kernel once: one joint seen from two limbs, one bone."""
    rot = np.repeat(np.eye(3)[None], 2, axis=0)
    trans = np.zeros((2, 3))
    joints = np.zeros((2, 3))
    model = joint_model(np.array([0, 0, 1, 1]), np.array([[0.0, 0, 0], [0, 0, 0.3], [0, 0, 0], [0, 0, 0.3]]),
                       np.array([0, 1, 1, 1]), np.ones(4), np.full(4, 1e-6), np.full(2, 5e-3), np.array([1]),
                       np.array([0]), np.array([0.3]))
    joints_all_seen(rot, trans, np.array([3, 3]), np.full(2, 1e-3), model, joints)
