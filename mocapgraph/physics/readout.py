"""The read-out of a physics world: published geom poses and tracking errors, simulated characters.

What the tracker publishes each step: every published geom's position (m), orientation (wxyz,
w >= 0) and tracking error (m, the mean of a capsule's two joints' distances to their targets; NaN
for stage geoms), and each simulated character's joint positions, local rotations and root. World
frame Z up. Runs as :mod:`.state_kernels` (or, in the tests, their numpy references).
"""
from __future__ import annotations

from typing import Callable

import mujoco
import numpy as np

from . import state_kernels as sk
from .body import CharacterBody
from .controller import cross
from .index import WorldIndex

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
SHAPES = {mujoco.mjtGeom.mjGEOM_BOX: "box", mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
          mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule", mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder"}


class Readout:
    """Reads the state of one world (see the module docstring)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, index: WorldIndex, bodies: list[CharacterBody],
                 geom_state_into: Callable, local_rotations_into: Callable) -> None:
        self.model, self.data, self.index = model, data, index
        self._point_err = np.zeros(len(index.pt_body))
        self._layout = tuple(sk.GeomLayout(index.geom_ids, index.pt_site, np.ascontiguousarray(index.geom_joints[:, 0]),
                                           np.ascontiguousarray(index.geom_joints[:, 1]), self._point_err))
        self._local = []   # per character: ball qpos addresses, their joints, root address and joint, rest
        for k, cb in enumerate(bodies):
            ch = cb.character
            adr = np.asarray(index.qpos_adr[k], dtype=np.int64)
            is_root = cb.body_joints == ch.root
            self._local.append((np.ascontiguousarray(adr[~is_root]),
                                np.ascontiguousarray(cb.body_joints[~is_root], dtype=np.int64),
                                int(adr[is_root][0]), int(ch.root),
                                np.ascontiguousarray(ch.rest_rotations[ch.root], dtype=np.float64)))
        self._ident = [np.tile(IDENTITY, (cb.character.n_joints, 1)) for cb in bodies]
        self._geom_state, self._local_rotations = geom_state_into, local_rotations_into

    def geom_state(self, p_t: np.ndarray, override: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Published geoms: positions [G, 3] m, orientations [G, 4] wxyz, tracking error [G] m,
        against targets ``p_t`` [N, 3] (``override`` [N, 3] where set)."""
        d = self.data
        G = len(self.index.geom_ids)
        pos, quat, err = np.empty((G, 3)), np.empty((G, 4)), np.empty(G)
        self._geom_state(d.geom_xpos, d.geom_xmat, d.site_xpos, self._layout, p_t, override, pos, quat, err)
        return pos, quat, err

    def tracking_error(self, p_t: np.ndarray, override: np.ndarray) -> np.ndarray:
        """Per stacked joint: distance from the simulated joint to its target, m (NaN: no target)."""
        self.geom_state(p_t, override)
        return self._point_err.copy()

    def geom_shapes(self) -> tuple[tuple[str, ...], np.ndarray]:
        """Shape names and MuJoCo sizes [G, 3] of the published geoms."""
        ids = self.index.geom_ids
        return tuple(SHAPES.get(int(t), "mesh") for t in self.model.geom_type[ids]), self.model.geom_size[ids].copy()

    def point_positions(self) -> np.ndarray:
        """World positions [N, 3] of every character joint (stacked), m: its site's."""
        return self.data.site_xpos[self.index.pt_site]

    def point_velocities(self, p: np.ndarray) -> np.ndarray:
        """World velocities [N, 3] (m/s) of the points ``p`` riding their bodies (from ``cvel``)."""
        d = self.data
        cv = d.cvel[self.index.pt_body]
        return cv[:, 3:] + cross(cv[:, :3], p - d.subtree_com[self.index.pt_root])

    def joint_positions(self, k: int) -> np.ndarray:
        """Simulated joint positions [J, 3] of character ``k``, m, world."""
        return self.point_positions()[self.index.point_slice[k]]

    def local_rotations(self, k: int, leaf_rotations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Simulated character ``k`` as (local rotations [J, 4] wxyz, root position [3] m).

        Joints without a body (leaves) take ``leaf_rotations`` (their target's) or identity."""
        ball_adr, ball_joints, root_adr, root_joint, rest_root = self._local[k]
        out = self._ident[k].copy() if leaf_rotations is None else np.array(leaf_rotations, dtype=np.float64, order="C")
        root_pos = np.empty(3)
        self._local_rotations(self.data.qpos, ball_adr, ball_joints, root_adr, root_joint, rest_root, out, root_pos)
        return out, root_pos

    def lowest_point(self, k: int) -> float:
        """Height (m, world z; the floor is 0) of the lowest point of character ``k``'s capsules."""
        g = self.index.char_capsules[k]
        d, m = self.data, self.model
        axis_z = np.abs(d.geom_xmat[g, 8])   # the capsule axis (geom z) against world z
        return float((d.geom_xpos[g, 2] - axis_z * m.geom_size[g, 1] - m.geom_size[g, 0]).min())
