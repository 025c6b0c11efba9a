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

Runs as :mod:`.posture_kernels`; :class:`.reference.ReferenceConditioner` is the numpy reference
the tests hold it to.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..retarget.character import Character
from . import posture_kernels as pk
from .posture_db import PostureDB


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

    def __init__(self, character: Character, db: PostureDB | None = None) -> None:
        if db is not None and tuple(db.joint_names) != tuple(character.joint_names):
            raise ValueError(f"posture database joints {len(db.joint_names)} do not match character "
                             f"{character.name!r} ({character.n_joints} joints)")
        self.character = character
        self.db = db
        self.last: Conditioned | None = None
        self.filled_frames = 0
        self.held_frames = 0
        self.profile: dict[str, float] | None = None   # set to {} to sum CPU s of the database part
        J = character.n_joints
        self._skel = tuple(pk.Skeleton(int(character.root),
                                       np.ascontiguousarray(np.concatenate(character._levels), dtype=np.int64),
                                       np.ascontiguousarray(character.parents, dtype=np.int64),
                                       np.ascontiguousarray(character.rest_rotations, dtype=np.float64)))
        self._noq = np.zeros(J, dtype=np.int8)
        self._q_in = np.zeros(J, dtype=np.int8)
        self._pos_in = np.zeros((J, 3))
        self._rot_in = np.zeros((J, 4))
        self._root_in = np.zeros(3)
        self._J = J

    def condition(self, positions: np.ndarray, local_rotations: np.ndarray, root: np.ndarray,
                  quality: np.ndarray | None = None) -> Conditioned:
        """``quality`` [J] (0 missing, 1 estimated, 2 good): with a database, joints below 2 are
        replaced by the match (a held value is what the database should beat). Fresh output arrays
        every frame (the last target is kept by reference for holding)."""
        J = self._J
        # copied into this conditioner's own writable buffers (a few us): arrays decoded from
        # messages are read-only, and numba compiles every kernel again for each mix of read-only
        # and writable arguments (seconds, on a node's first frame)
        pos_in, rot_in = self._pos_in, self._rot_in
        pos_in[:] = np.reshape(positions, (J, 3))
        rot_in[:] = np.reshape(local_rotations, (J, 4))
        self._root_in[:] = np.reshape(root, 3)
        root = self._root_in
        db = self.db
        use_q = quality is not None and db is not None
        q = self._noq
        if use_q:
            q = self._q_in
            q[:] = np.reshape(quality, J)
        pos, rot = np.empty((J, 3)), np.empty((J, 4))
        if db is not None and db.search_compiled == "brute" and self.profile is None:
            # the usual frame: one kernel call for all of it
            orient, filled = np.empty((J, 4)), np.empty(J, bool)
            match = pk.condition_brute(pos_in, rot_in, root, q, use_q, self._skel, db.kernel_arrays, pos, rot,
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
        pk.orient(pos, rot, root, self._skel, orient)
        out = Conditioned(pos, orient, filled, False, match)
        self.last = out
        return out

    def _hold(self) -> Conditioned:
        self.held_frames += 1
        if self.last is None:
            J = self.character.n_joints
            return Conditioned(np.full((J, 3), np.nan), np.full((J, 4), np.nan), np.zeros(J, bool), True, -1)
        return Conditioned(self.last.positions, self.last.orientations, self.last.filled, True, self.last.match)
