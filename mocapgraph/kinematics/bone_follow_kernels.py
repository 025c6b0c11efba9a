"""Compiled one-frame :func:`bone_follow.unfollowed`: flags joints estimated whose bones the character could not follow."""
from __future__ import annotations

import numpy as np

from mocapgraph.jit import kernel


@kernel
def flag_unfollowed(pos, pts, joint, child, a, b, A, cos_limit, quality):
    """One frame: joint positions [J, 3] and source points [P, 3] (m); per checked bone [B] the owner
    and child joints, source points a -> b, A [B, 3, 3] and cos_limit (see bone_follow.BoneChecks).
    Lowers quality [J] (int8, in place) to 1 (estimated) for a joint with a bone beyond its limit;
    returns how many joints it lowered."""
    lowered = 0
    for i in range(joint.shape[0]):
        j, k = joint[i], child[i]
        c0, c1, c2 = pos[k, 0] - pos[j, 0], pos[k, 1] - pos[j, 1], pos[k, 2] - pos[j, 2]
        d0, d1, d2 = pts[b[i], 0] - pts[a[i], 0], pts[b[i], 1] - pts[a[i], 1], pts[b[i], 2] - pts[a[i], 2]
        s0 = A[i, 0, 0] * d0 + A[i, 0, 1] * d1 + A[i, 0, 2] * d2
        s1 = A[i, 1, 0] * d0 + A[i, 1, 1] * d1 + A[i, 1, 2] * d2
        s2 = A[i, 2, 0] * d0 + A[i, 2, 1] * d1 + A[i, 2, 2] * d2
        n = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2) * np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if n > 0.0 and c0 * s0 + c1 * s1 + c2 * s2 < cos_limit[i] * n and quality[j] > 1:
            quality[j] = 1
            lowered += 1
    return lowered


def warm() -> None:
    """Compile (and cache) the kernel on a two-joint frame."""
    i = np.zeros(1, dtype=np.int64)
    flag_unfollowed(np.array([[0.0, 0, 0], [0, 0, 1.0]]), np.array([[0.0, 0, 0], [0, 1.0, 0]]), i, i + 1, i, i + 1,
                    np.eye(3)[None], np.array([0.98]), np.full(2, 2, np.int8))
