"""Input conditioning for the physics world: one character's incoming pose to a safe target.

Per frame of a character (positions [J, 3] m, local rotations [J, 4] wxyz, root [3] m, world):

* missing joints (non-finite rows, or quality below good) are filled from the posture database
  (P_e, Θ_e, section 5);
  without a database they get no target (no force, no torque) rather than a guess;
* a frame with nothing usable, or a stream that stops, keeps the last good target: the character
  stands and waits;
* a target jump (a joint further than ``jump_m`` from where it was a frame ago) is not followed at
  once: the world clips target velocities and bounds the forces, so the body moves there at a
  bounded pace;
* world joint orientations for Eq 2 come from the character's forward kinematics of Θ_e.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..kinematics.character import Character
from . import posture_kernels as pk
from .posture_db import PostureDB
from .quat_lean import qmul


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


_qmul = qmul  # the one-matmul product (quat_lean)


def world_orientations(local: np.ndarray, rest: np.ndarray, parents: np.ndarray, levels) -> np.ndarray:
    """World orientations [J, 4] (wxyz) of local rotations [J, 4]: W[j] = W[parent] rest[j] local[j],
    by quaternion products one depth level at a time (the character's matrix FK costs 10x more)."""
    joint = _qmul(rest, local)
    world = np.empty_like(joint)
    world[levels[0]] = joint[levels[0]]
    for level in levels[1:]:
        world[level] = _qmul(world[parents[level]], joint[level])
    return world


@dataclass
class Conditioned:
    """What went into the world this frame."""

    positions: np.ndarray      # [J, 3] m, NaN where no target
    orientations: np.ndarray   # [J, 4] wxyz world, NaN where no target
    filled: np.ndarray         # [J] bool, taken from the database
    held: bool                 # the whole frame was unusable: the last target was kept
    match: int                 # database posture used, -1 none


class TargetConditioner:
    """Turns one character's incoming poses into world targets (see the module docstring)."""

    def __init__(self, character: Character, db: PostureDB | None = None, compiled: bool = True) -> None:
        if db is not None and tuple(db.joint_names) != tuple(character.joint_names):
            raise ValueError(f"posture database joints {len(db.joint_names)} do not match character "
                             f"{character.name!r} ({character.n_joints} joints)")
        self.character = character
        self.db = db
        self._levels = character._levels
        self.last: Conditioned | None = None
        self.filled_frames = 0
        self.held_frames = 0
        self.compiled = compiled      # kernels (posture_kernels); False: the numpy reference
        self.profile: dict[str, float] | None = None   # set to {} to sum CPU s of the database part
        self._k_order = np.ascontiguousarray(np.concatenate(self._levels), dtype=np.int64)
        self._k_parents = np.ascontiguousarray(character.parents, dtype=np.int64)
        self._k_rest = np.ascontiguousarray(character.rest_rotations, dtype=np.float64)
        self._k_noq = np.zeros(character.n_joints, dtype=np.int8)
        self._k_q_in = np.zeros(character.n_joints, dtype=np.int8)
        self._k_pos_in = np.zeros((character.n_joints, 3))
        self._k_rot_in = np.zeros((character.n_joints, 4))
        self._k_root_in = np.zeros(3)
        self._k_root = int(character.root)
        self._k_J = int(character.n_joints)

    def condition(self, positions: np.ndarray, local_rotations: np.ndarray, root: np.ndarray,
                  quality: np.ndarray | None = None) -> Conditioned:
        """``quality`` [J] (0 missing, 1 estimated, 2 good): with a database, joints below 2 are
        replaced by the match (a held value is what the database should beat)."""
        if self.compiled:
            return self._condition_compiled(positions, local_rotations, root, quality)
        return self._condition_numpy(positions, local_rotations, root, quality)

    def _condition_compiled(self, positions, local_rotations, root, quality) -> Conditioned:
        """:meth:`condition` as kernels (``posture_kernels``); fresh output arrays every frame (the
        last target is kept by reference for holding)."""
        J = self._k_J
        # copied into this conditioner's own writable buffers (a few us): arrays decoded from
        # messages are read-only, and numba compiles every kernel again for each mix of read-only
        # and writable arguments (seconds, on a node's first frame)
        pos_in, rot_in = self._k_pos_in, self._k_rot_in
        pos_in[:] = np.reshape(positions, (J, 3))
        rot_in[:] = np.reshape(local_rotations, (J, 4))
        self._k_root_in[:] = np.reshape(root, 3)
        root = self._k_root_in
        db = self.db
        use_q = quality is not None and db is not None
        q = self._k_noq
        if use_q:
            q = self._k_q_in
            q[:] = np.reshape(quality, J)
        pos, rot = np.empty((J, 3)), np.empty((J, 4))
        if db is not None and db.search_compiled == "brute" and self.profile is None:
            # the usual frame: one kernel call for all of it
            orient, filled = np.empty((J, 4)), np.empty(J, bool)
            match = pk.condition_brute(pos_in, rot_in, root, q, use_q, self._k_root, self._k_order, self._k_parents,
                                       self._k_rest, db._k_pl, db._k_pr, db._k_mean, db._k_basis, db._k_reduced_t,
                                       db._k_sqnorm, db._k_dist, db._k_pos, db._k_rot, db._k_q, db._k_info, pos, rot,
                                       orient, filled)
            if match == -2:
                return self._hold()
            # a match fills at least one joint (the frame had one missing); no match fills none
            self.filled_frames += match >= 0
            out = Conditioned(pos, orient, filled, False, match)
            self.last = out
            return out
        state = pk.clean(pos_in, rot_in, q, use_q, pos, rot)
        if state < 0:
            return self._hold()
        filled = np.zeros(J, bool)
        match = -1
        if state > 0 and self.db is not None:
            t = time.thread_time() if self.profile is not None else 0.0
            match = self.db.complete_into(pos, rot, filled)
            if self.profile is not None:
                self.profile["database"] = self.profile.get("database", 0.0) + time.thread_time() - t
            self.filled_frames += bool(filled.any())
        orient = np.empty((J, 4))
        pk.orient(pos, rot, root, self._k_root, self._k_order, self._k_parents, self._k_rest, orient)
        out = Conditioned(pos, orient, filled, False, match)
        self.last = out
        return out

    def _condition_numpy(self, positions, local_rotations, root, quality) -> Conditioned:
        """The numpy reference of :meth:`condition`."""
        ch = self.character
        pos = np.asarray(positions, float).reshape(ch.n_joints, 3)
        rot = np.asarray(local_rotations, float).reshape(ch.n_joints, 4)
        root = np.asarray(root, float).reshape(3)
        n2 = (rot * rot).sum(1)
        bad_rot = ~((n2 >= 0.999 ** 2) & (n2 <= 1.001 ** 2))   # |q| off 1 by over 1e-3, or not finite
        rot = np.where(bad_rot[:, None], np.nan, rot)
        ok_p = np.isfinite(pos).all(1)
        if not ok_p.any():
            return self._hold()
        if quality is not None and self.db is not None:
            unsure = np.asarray(quality) < 2
            if unsure.all():
                return self._hold()
            pos = np.where(unsure[:, None], np.nan, pos)
            rot = np.where(unsure[:, None], np.nan, rot)
            ok_p &= ~unsure
            bad_rot |= unsure
        filled = np.zeros(ch.n_joints, bool)
        match = -1
        if self.db is not None and ((~ok_p).any() or bad_rot.any()):
            t = time.thread_time() if self.profile is not None else 0.0
            pos, rot, filled, match = self.db.complete(pos, rot)
            if self.profile is not None:
                self.profile["database"] = self.profile.get("database", 0.0) + time.thread_time() - t
            self.filled_frames += bool(filled.any())
        ok_r = np.isfinite(rot).all(1)
        if not np.isfinite(root).all():
            root = pos[ch.root] if np.isfinite(pos[ch.root]).all() else None
        orient = np.full((ch.n_joints, 4), np.nan)
        if root is not None:
            # a missing rotation turns with its parent (identity) and its orientation (and those
            # below) are marked unknown
            chain_ok = ok_r.copy()
            if not chain_ok.all():  # the usual frame has every rotation: nothing to propagate
                for level in self._levels[1:]:
                    chain_ok[level] &= chain_ok[ch.parents[level]]
            world = world_orientations(np.where(ok_r[:, None], rot, IDENTITY), ch.rest_rotations, ch.parents,
                                       self._levels)
            orient = np.where(chain_ok[:, None], world, np.nan)
        out = Conditioned(np.where(np.isfinite(pos).all(1)[:, None], pos, np.nan), orient, filled, False, match)
        self.last = out
        return out

    def _hold(self) -> Conditioned:
        self.held_frames += 1
        if self.last is None:
            J = self.character.n_joints
            return Conditioned(np.full((J, 3), np.nan), np.full((J, 4), np.nan), np.zeros(J, bool), True, -1)
        return Conditioned(self.last.positions, self.last.orientations, self.last.filled, True, self.last.match)
