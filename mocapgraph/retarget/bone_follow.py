"""Which character joints could not follow their source bones: bone angles beyond the rest-shape difference.

A character joint with a source point and children with source points owns those bones. Its bone
(world, character) and the source's (world, turned by the mapping's A onto the character's axes)
differ at rest by the two rest poses' shape (0 for Kinect onto standard_20, whose T-pose is built
from it; CMU's pelvis V onto Mixamo's keeps 20 deg); a frame whose angle exceeds that by more than a
tolerance (deg) is one the joint could not follow (a rigid girdle under an asymmetric shrug): the
retargeter flags the joint estimated (1) there, never good. The joint alone: its descendants' own
bones still follow theirs. Numpy reference here (batched over frames); the retargeter's one-frame
path runs kernels.flag_unfollowed (the same arithmetic compiled).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.quaternion import quat_to_matrix


@dataclass(frozen=True, eq=False)
class BoneChecks:
    """The bones checked: owner joint, child joint [B] (character indices), source points a -> b [B],
    A [B, 3, 3] (source world -> character world), cos_limit [B] (cos of rest angle + tolerance;
    -2: never flagged)."""

    joint: np.ndarray
    child: np.ndarray
    a: np.ndarray
    b: np.ndarray
    A: np.ndarray
    cos_limit: np.ndarray

    @property
    def empty(self) -> bool:
        return self.joint.size == 0


def plan_bone_checks(ch, mapping, src, tolerance_deg: float | None) -> BoneChecks:
    """Every mapped bone whose two ends have source points (both rest bones longer than 1e-6 m),
    limits from the rest angle plus ``tolerance_deg``; None or not finite checks none."""
    by = {e.joint: e for e in mapping.joints}
    cpos, _ = ch.rest_pose()
    rows = []
    if tolerance_deg is not None and np.isfinite(tolerance_deg):
        for j, name in enumerate(ch.joint_names):
            e = by.get(name)
            if e is None or e.position is None:
                continue
            for k in ch.children(j):
                ek = by.get(ch.joint_names[k])
                if ek is None or ek.position is None:
                    continue
                a, b = src.point(e.position), src.point(ek.position)
                A = quat_to_matrix(np.asarray(e.A, dtype=np.float64))
                s, c = A @ (src.rest_points[b] - src.rest_points[a]), cpos[k] - cpos[j]
                if np.linalg.norm(s) < 1e-6 or np.linalg.norm(c) < 1e-6:
                    continue
                rest = np.degrees(np.arccos(np.clip(s @ c / np.linalg.norm(s) / np.linalg.norm(c), -1.0, 1.0)))
                limit = rest + float(tolerance_deg)
                rows.append((j, int(k), a, b, A, np.cos(np.radians(limit)) if limit < 180.0 else -2.0))
    if not rows:
        z = np.zeros(0, dtype=np.int64)
        return BoneChecks(z, z, z, z, np.zeros((0, 3, 3)), np.zeros(0))
    return BoneChecks(*(np.array([r[i] for r in rows], dtype=np.int64) for i in range(4)),
                      np.array([r[4] for r in rows]), np.array([r[5] for r in rows], dtype=np.float64))


def unfollowed(checks: BoneChecks, joint_positions: np.ndarray, points: np.ndarray) -> np.ndarray:
    """[F, J] True where a joint's bone (character joint positions [F, J, 3], m) turned from the
    source's (points [F, P, 3], m) by more than its limit; a zero-length or non-finite bone is not
    judged (its point quality says what is known)."""
    F, J = joint_positions.shape[:2]
    out = np.zeros((F, J), bool)
    if checks.empty:
        return out
    c = joint_positions[:, checks.child] - joint_positions[:, checks.joint]            # [F, B, 3]
    s = np.einsum("bij,fbj->fbi", checks.A, points[:, checks.b] - points[:, checks.a])
    n = np.linalg.norm(c, axis=-1) * np.linalg.norm(s, axis=-1)
    with np.errstate(invalid="ignore"):
        bad = (n > 0) & (np.sum(c * s, -1) < checks.cos_limit * n)
    np.logical_or.at(out, (slice(None), checks.joint), bad)
    return out
