"""One MuJoCo world of characters tracking target poses on a stage (Shum & Ho, sections 4 and 6).

Per input frame: :meth:`PhysicsWorld.set_target` takes each character's target joint positions
``P_e`` and world joint orientations (``Θ_e``), both world frame (m, wxyz); :meth:`step` advances
the frame's span in substeps of ``timestep``, each computing Eq 1 forces at every joint and Eq 2
twist torques on every body from the current state (``mj_step1``), applying them through
``xfrc_applied`` as the force at the joint point plus its moment about the body's centre of mass
(exactly ``mj_applyFT`` at the joint; a test checks), then integrating (``mj_step2``). Joint
points are MuJoCo sites (``site_xpos``); gravity compensation is MuJoCo's ``gravcomp``; all
body wrenches of a substep are one matmul into ``xfrc_applied``.

Virtual joints (section 6.1) are MuJoCo ``connect`` constraints between a foot point and a mocap
pin: switched on where the foot's input target is on the floor and still, placed where the simulated
foot is, drawn after a target that drifts from it at a bounded horizontal speed (a pivoting foot),
and off when the target lifts, speeds up or jumps away; a held object is a ``weld`` to the hand's body.
Positional constraints replace some targets: ``set_override`` (a hand onto an object, ``reach``)
and the automatic dodge (forearm targets raised around the head while a ball comes at it, Figure 4).

Frames: world Z up, X forward; SI units. All per-step math is vectorised over every joint and body
of every character at once.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import mujoco
import numpy as np
from scipy.sparse import csr_matrix

from ..kinematics.character import Character
from ..kinematics.quaternion import matrix_to_quat, quat_conjugate, quat_multiply, quat_to_matrix
from .anthropometry import bone_masses
from .body import CharacterBody, add_character, add_pins, character_body, fmt, to_xml, world_root
from . import controller_kernels as ck
from . import state_kernels as sk
from .controller import Gains, clip_norm, cross, twist_torques
from .quat_lean import qmul_conj as _qmul_conj
from .stage import EMPTY_STAGE, PARK_X, Stage, add_stage

import xml.etree.ElementTree as ET

GRAVITY = np.array([0.0, 0.0, -9.81])


def tick(profile: dict[str, float], stage: str, since: float) -> float:
    """Add the thread CPU time since ``since`` (s) to ``profile[stage]``; returns now."""
    now = time.thread_time()
    profile[stage] = profile.get(stage, 0.0) + (now - since)
    return now


IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
TRUNK_CLASSES = ("lower_trunk", "middle_trunk", "upper_trunk", "head")   # anthropometry's segment classes


@dataclass
class TrackerParams:
    """Simulation and control settings (SI units)."""

    timestep: float = 1.0 / 240.0      # s, MuJoCo step (1/120 is unstable with these gains)
    gains: Gains = field(default_factory=Gains)
    body_mass: float = 70.0            # kg per character
    virtual_joints: bool = True        # pin supporting feet
    contact_height: float = 0.03       # m: a foot target this close to its rest height is on the floor
    contact_speed: float = 0.25        # m/s: ... and slower than this horizontally
    pin_slack: float = 0.05            # m: a pin lets go when its target is this far from it (a jump), and
                                       # a foot this far from its target is not pinned (it catches up first)
    pin_hold: float = 0.02             # m: a pinned foot stays put while its target is this close to it
                                       # (Kinect v2 feet jitter by 1-2 cm: 1 cm made pins follow the noise)
    pin_follow_speed: float = 0.18     # m/s: ... and beyond, follows it at most this fast horizontally
                                       # (1.5 mm a frame at 120 Hz: a foot pivoting in a turn)
    dodge: bool = False                # raise the forearms when a ball comes at the head
    dodge_horizon_s: float = 0.45      # s ahead a ball is seen coming
    joint_damping: float = 1.0         # N·m·s/rad in every ball joint
    max_target_speed: float = 6.0      # m/s: faster target velocities (jumps, glitches) are clipped
    gravity_compensation: float = 0.5  # fraction of each body's weight held up at its centre of mass
    foot_max_force: float = 40.0       # N, Eq 1 bound at the ankles and feet (<= gains.max_force)
    trunk_max_force: float = 60.0      # N, Eq 1 bound at the trunk's joints and the head (<= gains.max_force)
    compiled: bool = True              # per-frame control as numba kernels; False: the numpy reference


@dataclass
class _Push:
    character: int
    point: int          # index into the stacked points
    force: np.ndarray   # N, world
    until: float        # sim time, s


class PhysicsWorld:
    """Characters and a stage in one MuJoCo world, each character tracking its own target."""

    def __init__(self, characters: list[Character], stage: Stage = EMPTY_STAGE,
                 params: TrackerParams | None = None, spawns: list | None = None) -> None:
        self.params = params or TrackerParams()
        self.params.gains.check()
        if not characters:
            raise ValueError("a physics world needs at least one character")
        if spawns is None:
            spawns = [np.array([0.0, 1.5 * k, 0.0]) for k in range(len(characters))]
        self.stage = stage
        self.bodies = [character_body(c, k, self.params.body_mass, spawns[k]) for k, c in enumerate(characters)]
        self.xml = build_xml(self.bodies, stage, self.params)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        self._index()
        self.time_of_target = [None] * len(self.bodies)
        self.frames_stepped = 0
        self.max_applied_force = 0.0     # N, largest Eq 1 force ever applied
        self.max_applied_torque = 0.0    # N·m, largest Eq 2 torque ever applied
        self.resets = 0                  # times the state went non-finite and was reset to the target
        self.profile: dict[str, float] | None = None   # set to {} to sum CPU s per stage of step()
        self._pushes: list[_Push] = []
        self._next_ball = 0
        self._dodge_until = np.full(len(self.bodies), -np.inf)
        mujoco.mj_forward(self.model, self.data)

    # ----- indexing ----------------------------------------------------------------------------
    def _index(self) -> None:
        m = self.model
        name = lambda kind, n: mujoco.mj_name2id(m, kind, n)  # noqa: E731
        pts_body, pts_local, pts_char, bodies, axes, body_char, body_joint = [], [], [], [], [], [], []
        self.point_slice, self.body_slice, self.qpos_adr = [], [], []
        self.pin_eq, self.pin_mocap, self.pin_point, self.pin_rest_z = [], [], [], []
        for k, cb in enumerate(self.bodies):
            bid = np.array([name(mujoco.mjtObj.mjOBJ_BODY, cb.body_name(int(j))) for j in cb.body_joints])
            a = len(pts_body)
            pts_body += list(bid[cb.joint_body])
            pts_local += list(cb.joint_point)
            pts_char += [k] * cb.character.n_joints
            self.point_slice.append(slice(a, len(pts_body)))
            b0 = len(bodies)
            bodies += list(bid)
            axes += list(cb.twist_axis)
            body_char += [k] * len(bid)
            body_joint += list(cb.body_joints)
            self.body_slice.append(slice(b0, len(bodies)))
            jnt = m.body_jntadr[bid]
            self.qpos_adr.append(m.jnt_qposadr[jnt])
            rest, _ = cb.character.rest_pose()
            for f in cb.feet:
                self.pin_eq.append(name(mujoco.mjtObj.mjOBJ_EQUALITY, f"{cb.prefix}pin/{cb.character.joint_names[f]}"))
                self.pin_mocap.append(m.body_mocapid[name(mujoco.mjtObj.mjOBJ_BODY, cb.pin_name(int(f)))])
                self.pin_point.append(a + int(f))
                self.pin_rest_z.append(rest[f, 2] + cb.spawn[2])
        self.pt_body = np.array(pts_body)
        self.pt_site = np.array([name(mujoco.mjtObj.mjOBJ_SITE, cb.site_name(j)) for cb in self.bodies
                                 for j in range(cb.character.n_joints)], dtype=np.int64)
        self.pt_local = np.array(pts_local, dtype=np.float64)
        self.pt_char = np.array(pts_char)
        self.pt_min_z = np.zeros(len(pts_body))
        for k, cb in enumerate(self.bodies):
            a = self.point_slice[k].start
            for c, r in zip(cb.bone_child, cb.bone_radius):
                for j in (int(c), int(cb.character.parents[c])):
                    self.pt_min_z[a + j] = max(self.pt_min_z[a + j], r)
        self.b_body = np.array(bodies)
        self.b_axis = np.array(axes, dtype=np.float64)
        self.b_char = np.array(body_char)
        self.b_joint = np.array(body_joint)
        self.b_root = m.body_rootid[self.b_body]
        self.pt_root = m.body_rootid[self.pt_body]
        self.pin_eq = np.array(self.pin_eq, dtype=np.int64)
        self.pin_mocap = np.array(self.pin_mocap, dtype=np.int64)
        self.pin_point = np.array(self.pin_point, dtype=np.int64)
        self.pin_rest_z = np.array(self.pin_rest_z)
        self.pin_on = np.zeros(len(self.pin_eq), dtype=bool)
        # body -> stacked rows: forces at points summed per body by one matrix product
        nb = m.nbody
        self._pt_to_body = np.zeros((nb, len(self.pt_body)))
        self._pt_to_body[self.pt_body, np.arange(len(self.pt_body))] = 1.0
        n = len(self.pt_body)
        self.p_t = np.full((n, 3), np.nan)
        self.v_t = np.zeros((n, 3))
        self.p_in = np.full((n, 3), np.nan)   # the input targets as given (before lifting), m
        self.v_in = np.zeros((n, 3))          # ... and their velocities, m/s: what foot contact is judged by
        self.q_t = np.tile([1.0, 0, 0, 0], (len(self.b_body), 1))
        self.w_t = np.zeros((len(self.b_body), 3))
        self.has_rot = np.zeros(len(self.b_body), dtype=bool)
        self.override = np.full((n, 3), np.nan)   # positional constraints (reach, dodge)
        self.dodge_override = np.full((n, 3), np.nan)
        self.last_forces = np.zeros((n, 3))
        self.last_torques = np.zeros((len(self.b_body), 3))
        self.scale_pt = np.ones(n)
        g = self.params.gains
        self._kp = (g.kp * self.scale_pt)[:, None]   # Eq 1 gains per point, N/m and N·s/m
        self._kd = (g.kd * self.scale_pt)[:, None]
        # Eq 1 bound per point: the gains' (the limbs' strength) everywhere, the feet's own at the
        # ankles and feet (a light foot driven with 400 N strikes the floor hard) and the trunk's at
        # the root, trunk joints and head (what holds the body where its target is, as balance
        # does: bounded low, so a push displaces the body rather than meeting a wall)
        self.force_bound = np.full(n, g.max_force)
        for k, cb in enumerate(self.bodies):
            a = self.point_slice[k].start
            ch = cb.character
            classes = bone_masses(ch, cb.body_mass).classes
            trunk = [j for j in range(ch.n_joints) if j == ch.root or classes[j] in TRUNK_CLASSES]
            self.force_bound[a + np.array(trunk, dtype=np.int64)] = min(g.max_force, self.params.trunk_max_force)
            foot = np.r_[cb.feet, ch.parents[cb.feet]].astype(np.int64)
            self.force_bound[a + foot] = min(g.max_force, self.params.foot_max_force)
        self._bound2 = self.force_bound ** 2
        # Eq 2 gains act per unit inertia about the twist axis (1/s^2, 1/s): a foot twisting with
        # the torso's gains in N·m/rad would be unstable at any usable timestep
        Rp = quat_to_matrix(m.body_iquat[self.b_body])
        a_p = (np.swapaxes(Rp, 1, 2) @ self.b_axis[:, :, None])[:, :, 0]
        self.scale_body = (m.body_inertia[self.b_body] * a_p ** 2).sum(1)
        self._has_override = False   # any positional constraint set (reach)
        self._dodging = False        # dodge targets set this frame
        self._b_axis_col = self.b_axis[:, :, None]
        # the character bodies' rows of mjData: a slice when contiguous (a view, not a gather)
        b = self.b_body
        self._b_rows = slice(int(b[0]), int(b[-1]) + 1) if (np.diff(b) == 1).all() else b
        self._has_rot_col = self.has_rot[:, None]   # a view: follows has_rot
        self._bad_warnings = np.array([mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQVEL,
                                       mujoco.mjtWarning.mjWARN_BADQPOS], dtype=np.int64)
        # xfrc_applied rows = A_ext @ [point wrenches; per-body extras]: one matmul per substep
        nb, npt = m.nbody, len(self.pt_body)
        self._A = np.zeros((nb, npt + nb))
        self._A[self.pt_body, np.arange(npt)] = 1.0
        self._A[np.arange(nb), npt + np.arange(nb)] = 1.0
        self._wrench = np.zeros((npt + nb, 6))
        # many characters: A is mostly zeros, and a dense product grows with the square of their
        # number (12 characters: 0.3 ms a substep); a sparse one stays linear
        self._A_sparse = csr_matrix(self._A) if self._A.size > 20000 else None
        # the compiled path's constant index arrays and per-frame buffers (contiguous int64/float64)
        self._k_site = np.ascontiguousarray(self.pt_site, dtype=np.int64)
        self._k_body = np.ascontiguousarray(self.pt_body, dtype=np.int64)
        self._k_root = np.ascontiguousarray(self.pt_root, dtype=np.int64)
        self._k_bbody = np.ascontiguousarray(self.b_body, dtype=np.int64)
        self._k_baxis = np.ascontiguousarray(self.b_axis, dtype=np.float64)
        self._k_scale = np.ascontiguousarray(self.scale_body, dtype=np.float64)
        self._k_kp = np.ascontiguousarray(self._kp[:, 0])
        self._k_kd = np.ascontiguousarray(self._kd[:, 0])
        self._k_bound = np.ascontiguousarray(self.force_bound, dtype=np.float64)
        self._k_c0, self._k_slope = np.zeros((n, 3)), np.zeros((n, 3))
        self._k_kpf, self._k_kdf = np.zeros(n), np.zeros(n)
        self._k_f, self._k_tq = np.zeros((n, 3)), np.zeros((len(self.b_body), 3))
        self._k_tops = np.zeros(2)
        self._k_joints = [np.ascontiguousarray(cb.body_joints, dtype=np.int64) for cb in self.bodies]
        self._k_parents = [np.ascontiguousarray(cb.character.parents, dtype=np.int64) for cb in self.bodies]
        self._k_pin_rest_z = np.ascontiguousarray(self.pin_rest_z, dtype=np.float64)
        # views into mjData (mj_resetData keeps its buffers): read every frame without a lookup
        self._k_warnings = self.data.warning.number
        self._k_bad = tuple(int(x) for x in self._bad_warnings)
        self._k_qvel = self.data.qvel
        self._k_ident = [np.tile(IDENTITY, (cb.character.n_joints, 1)) for cb in self.bodies]
        # published geoms: every character capsule and stage geom (not the floor)
        floor = name(mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self.geom_ids = np.array([g for g in range(m.ngeom) if g != floor])
        self.geom_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in self.geom_ids)
        # each character geom's two joints, for its tracking error
        self.geom_joints = -np.ones((len(self.geom_ids), 2), dtype=np.int64)
        lookup = {n_: i for i, n_ in enumerate(self.geom_names)}
        for k, cb in enumerate(self.bodies):
            a = self.point_slice[k].start
            for c in cb.bone_child:
                i = lookup[cb.geom_name(int(c))]
                self.geom_joints[i] = (a + int(cb.character.parents[c]), a + int(c))
        self._k_geoms = np.ascontiguousarray(self.geom_ids, dtype=np.int64)
        # each character's capsules (geom ids), to keep a pose put by set_pose out of the floor
        self._char_capsules = [np.array([self.geom_ids[lookup[cb.geom_name(int(c))]] for c in cb.bone_child],
                                        dtype=np.int64) for cb in self.bodies]
        self._k_gj0 = np.ascontiguousarray(self.geom_joints[:, 0])
        self._k_gj1 = np.ascontiguousarray(self.geom_joints[:, 1])
        self._k_point_err = np.zeros(len(self.pt_body))
        self._k_local = []   # per character: ball qpos addresses, their joints, root address and joint, rest
        for k, cb in enumerate(self.bodies):
            ch = cb.character
            adr = np.asarray(self.qpos_adr[k], dtype=np.int64)
            is_root = cb.body_joints == ch.root
            self._k_local.append((np.ascontiguousarray(adr[~is_root]),
                                  np.ascontiguousarray(cb.body_joints[~is_root], dtype=np.int64),
                                  int(adr[is_root][0]), int(ch.root),
                                  np.ascontiguousarray(ch.rest_rotations[ch.root], dtype=np.float64), ch.n_joints))
        self.ball_joint = [m.jnt_qposadr[m.body_jntadr[name(mujoco.mjtObj.mjOBJ_BODY, b)]] for b in self.stage.ball_names]
        self.ball_dof = [m.jnt_dofadr[m.body_jntadr[name(mujoco.mjtObj.mjOBJ_BODY, b)]] for b in self.stage.ball_names]
        self.ball_body = np.array([name(mujoco.mjtObj.mjOBJ_BODY, b) for b in self.stage.ball_names], dtype=np.int64)
        self.held = []  # (eq id, object body id, hand body id, object pose in the hand frame)
        d0 = mujoco.MjData(m)
        mujoco.mj_forward(m, d0)  # the model's own pose: where each weld is satisfied
        for o in self.stage.objects:
            if o.held_by is not None and o.held_by[0] < len(self.bodies):
                eq = name(mujoco.mjtObj.mjOBJ_EQUALITY, f"hold/{o.name}")
                obj = name(mujoco.mjtObj.mjOBJ_BODY, f"stage/{o.name}")
                hand = int(m.eq_obj1id[eq])
                Rh = d0.xmat[hand].reshape(3, 3)
                rel_p = Rh.T @ (d0.xpos[obj] - d0.xpos[hand])
                rel_q = quat_multiply(quat_conjugate(d0.xquat[hand]), d0.xquat[obj])
                self.held.append((eq, obj, hand, rel_p, rel_q))

    # ----- geometry of the current state -------------------------------------------------------
    def point_positions(self) -> np.ndarray:
        """World positions [N, 3] of every character joint (stacked), m: its site's."""
        return self.data.site_xpos[self.pt_site]

    def point_velocities(self, p: np.ndarray) -> np.ndarray:
        """World velocities [N, 3] (m/s) of the points ``p`` riding their bodies (from ``cvel``)."""
        d = self.data
        cv = d.cvel[self.pt_body]
        return cv[:, 3:] + cross(cv[:, :3], p - d.subtree_com[self.pt_root])

    def joint_positions(self, k: int) -> np.ndarray:
        """Simulated joint positions [J, 3] of character ``k``, m, world."""
        return self.point_positions()[self.point_slice[k]]

    def local_rotations(self, k: int, leaf_rotations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Simulated character ``k`` as (local rotations [J, 4] wxyz, root position [3] m).

        Joints without a body (leaves) take ``leaf_rotations`` (their target's) or identity."""
        if self.params.compiled:
            ball_adr, ball_joints, root_adr, root_joint, rest_root, J = self._k_local[k]
            out = self._k_ident[k].copy() if leaf_rotations is None else \
                np.array(leaf_rotations, dtype=np.float64, order="C")
            root_pos = np.empty(3)
            sk.local_rotations_into(self.data.qpos, ball_adr, ball_joints, root_adr, root_joint, rest_root, out,
                                    root_pos)
            return out, root_pos
        cb = self.bodies[k]
        ch = cb.character
        adr = self.qpos_adr[k]
        q = self.data.qpos
        out = np.tile([1.0, 0, 0, 0], (ch.n_joints, 1)) if leaf_rotations is None else np.array(leaf_rotations, float)
        root = int(np.flatnonzero(cb.body_joints == ch.root)[0])
        ball = adr[np.arange(len(adr)) != root]
        joints = cb.body_joints[np.arange(len(adr)) != root]
        out[joints] = q[ball[:, None] + np.arange(4)]
        r = adr[root]
        out[ch.root] = quat_multiply(quat_conjugate(ch.rest_rotations[ch.root]), q[r + 3:r + 7])
        out /= np.linalg.norm(out, axis=1, keepdims=True)
        return out, q[r:r + 3].copy()

    # ----- targets -----------------------------------------------------------------------------
    def set_pose(self, k: int, local_rotations: np.ndarray, root_position: np.ndarray) -> None:
        """Put character ``k`` exactly in a pose (local rotations wxyz [J,4], root m), at rest, raised
        onto the floor when a capsule would reach into it."""
        cb = self.bodies[k]
        ch = cb.character
        adr = self.qpos_adr[k]
        q = self.data.qpos
        loc = np.asarray(local_rotations, float)
        for b, j in enumerate(cb.body_joints):
            a = adr[b]
            if j == ch.root:
                q[a:a + 3] = root_position
                q[a + 3:a + 7] = quat_multiply(ch.rest_rotations[j], loc[j])
            else:
                q[a:a + 4] = loc[j]
        dof = self.model.body_dofadr[self.b_body[self.body_slice[k]]]
        ndof = self.model.body_dofnum[self.b_body[self.body_slice[k]]]
        for a, n in zip(dof, ndof):
            self.data.qvel[a:a + n] = 0.0
        mujoco.mj_forward(self.model, self.data)
        # a pose reaching into the floor (a heel strike cutting it, a source whose floor is not
        # ours) is raised onto it: a body started 5 cm or more deep blows MuJoCo's contact solver
        # up on its first step (and the node's reset put it back there, again and again)
        low = self.lowest_point(k)
        if low < 0.0:
            r = adr[int(np.flatnonzero(cb.body_joints == ch.root)[0])]
            q[r + 2] -= low
            mujoco.mj_forward(self.model, self.data)
        self._snap_held()
        self.pin_on[self.pin_char == k] = False
        self.data.eq_active[self.pin_eq[self.pin_char == k]] = 0

    def lowest_point(self, k: int) -> float:
        """Height (m, world z; the floor is 0) of the lowest point of character ``k``'s capsules."""
        g = self._char_capsules[k]
        d, m = self.data, self.model
        axis_z = np.abs(d.geom_xmat[g, 8])   # the capsule axis (geom z) against world z
        return float((d.geom_xpos[g, 2] - axis_z * m.geom_size[g, 1] - m.geom_size[g, 0]).min())

    @property
    def pin_char(self) -> np.ndarray:
        return self.pt_char[self.pin_point]

    def set_target(self, k: int, positions: np.ndarray, orientations: np.ndarray, time_s: float) -> None:
        """Target of character ``k``: joint positions [J, 3] m and world joint orientations [J, 4]
        wxyz (NaN rows: no target for that joint), at input time ``time_s`` (for the velocities)."""
        prev_t = self.time_of_target[k]
        if self.params.compiled:
            p = np.ascontiguousarray(positions, dtype=np.float64)
            q = np.ascontiguousarray(orientations, dtype=np.float64)
            ck.set_target_into(p, q, self._k_joints[k], self.point_slice[k].start, self.body_slice[k].start,
                               -1.0 if prev_t is None else float(time_s - prev_t), self.params.max_target_speed,
                               20.0, self._k_parents[k], self.pt_min_z, self.p_t, self.v_t, self.q_t, self.w_t,
                               self.has_rot, self.p_in, self.v_in)
            self.time_of_target[k] = time_s
            return
        self._set_target_numpy(k, positions, orientations, time_s)

    def _set_target_numpy(self, k: int, positions: np.ndarray, orientations: np.ndarray, time_s: float) -> None:
        """The numpy reference of :meth:`set_target` (``controller_kernels.set_target_into``)."""
        sl = self.point_slice[k]
        bs = self.body_slice[k]
        cb = self.bodies[k]
        p = np.asarray(positions, float)
        q = np.asarray(orientations, float)[cb.body_joints]
        prev_t = self.time_of_target[k]
        dt = None if prev_t is None else time_s - prev_t
        ok_p = np.isfinite(p).all(1)
        ok_q = np.isfinite(q).all(1)
        all_p, all_q = bool(ok_p.all()), bool(ok_q.all())
        # the floor is a constraint too: no target below a capsule's radius (a target foot under
        # the floor would press the body into it with the full bounded force)
        if not all_p:
            p = np.where(ok_p[:, None], p, np.nan)
        use_dt = dt is not None and 1e-4 < dt < 0.5
        if use_dt:   # the input's own velocity, what foot contact is judged by
            vi = (p - self.p_in[sl]) / dt
            vi[~np.isfinite(vi).all(1)] = 0.0
            self.v_in[sl] = vi
        else:
            self.v_in[sl] = 0.0
        self.p_in[sl] = p
        p = lift_above_floor(p, cb.character.parents, self.pt_min_z[sl])
        if use_dt:
            # the velocity of the target the body tracks (lifted now minus lifted before): the raw
            # input minus the last lifted target adds the lift's offset / dt (a toe swung up 20 mm
            # out of the floor read as 2.4 m/s and let go of a supporting foot's pin)
            v = (p - self.p_t[sl]) / dt
            if not math.isfinite(v.sum()):        # a joint or its previous target missing: no velocity
                v[~np.isfinite(v).all(1)] = 0.0
            self.v_t[sl] = _clip_rows(v, self.params.max_target_speed)
            # angular velocity of each target orientation: 2 vec(q q_prev^-1) / dt, small-angle
            # form (exact to 0.1 % below 6 degrees a frame; faster turns are clipped anyway)
            e = _qmul_conj(q, self.q_t[bs])
            w = e[:, 1:] * np.copysign(2.0 / dt, e[:, :1])
            if not (all_q and self.has_rot[bs].all()):
                w = np.where((ok_q & self.has_rot[bs])[:, None], w, 0.0)
            self.w_t[bs] = _clip_rows(w, 20.0)
        else:
            self.v_t[sl] = 0.0
            self.w_t[bs] = 0.0
        self.p_t[sl] = p
        if all_q:
            self.q_t[bs] = q
        else:
            self.q_t[bs] = np.where(ok_q[:, None], q, self.q_t[bs])
        self.has_rot[bs] = ok_q
        self.time_of_target[k] = time_s

    def set_override(self, k: int, joint: int | str, position: np.ndarray | None) -> None:
        """Positional constraint: joint ``joint`` of character ``k`` targets ``position`` (world m)
        instead of its input target, until set to None."""
        j = self.bodies[k].character.index(joint) if isinstance(joint, str) else int(joint)
        self.override[self.point_slice[k].start + j] = np.nan if position is None else position
        self._has_override = bool(np.isfinite(self.override).any())

    def reach(self, k: int, joint: int | str, geom: str) -> np.ndarray:
        """Move joint ``joint``'s target onto the surface of stage geom ``geom`` (the surface point
        nearest to the joint's current target) and return that point."""
        j = self.bodies[k].character.index(joint) if isinstance(joint, str) else int(joint)
        g = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, geom)
        if g < 0:
            raise KeyError(f"no stage geom {geom!r}")
        i = self.point_slice[k].start + j
        base = self.p_t[i] if np.isfinite(self.p_t[i]).all() else self.point_positions()[i]
        c = self.data.geom_xpos[g]
        R = self.data.geom_xmat[g].reshape(3, 3)
        size = self.model.geom_size[g]
        if self.model.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX:
            loc = np.clip(R.T @ (base - c), -size, size)
            if (np.abs(loc) < size).all():  # inside: out through the nearest face
                ax = int(np.argmin(size - np.abs(loc)))
                loc[ax] = np.copysign(size[ax], loc[ax])
            point = c + R @ loc
        else:
            d = base - c
            point = c + d / max(np.linalg.norm(d), 1e-9) * size[0]
        self.override[i] = point
        self._has_override = True
        return point

    # ----- interaction -------------------------------------------------------------------------
    def push(self, k: int, joint: int | str, force: np.ndarray, duration_s: float) -> None:
        """An external push (N, world) at joint ``joint`` of character ``k`` for ``duration_s``."""
        j = self.bodies[k].character.index(joint) if isinstance(joint, str) else int(joint)
        f = np.asarray(force, float)
        if f.shape != (3,) or not np.isfinite(f).all() or not np.isfinite(duration_s) or duration_s < 0:
            raise ValueError(f"push: force {force!r} must be 3 finite numbers, duration >= 0")
        self._pushes.append(_Push(k, self.point_slice[k].start + j, f, self.data.time + duration_s))

    def shoot(self, target: np.ndarray, speed: float | None = None, origin: np.ndarray | None = None) -> int:
        """Shoot the next ball of the stage's shooter at ``target`` (world m) on a ballistic arc;
        returns the ball's number."""
        sh = self.stage.shooter
        if sh is None:
            raise ValueError("this stage has no ball shooter")
        k = self._next_ball
        self._next_ball = (k + 1) % sh.pool
        o = sh.origin if origin is None else np.asarray(origin, float)
        target = np.asarray(target, float)
        s = sh.speed if speed is None else float(speed)
        dist = np.linalg.norm(target - o)
        T = dist / s
        v = (target - o) / T - 0.5 * GRAVITY * T
        a, dv = self.ball_joint[k], self.ball_dof[k]
        self.data.qpos[a:a + 3] = o
        self.data.qpos[a + 3:a + 7] = (1, 0, 0, 0)
        self.data.qvel[dv:dv + 3] = v
        self.data.qvel[dv + 3:dv + 6] = 0
        return k

    def park_balls(self) -> None:
        """Every ball back to its parking place, at rest."""
        for k, (a, dv) in enumerate(zip(self.ball_joint, self.ball_dof)):
            self.data.qpos[a:a + 7] = (PARK_X + 0.5 * k, 0, self.stage.shooter.radius, 1, 0, 0, 0)
            self.data.qvel[dv:dv + 6] = 0

    def set_held(self, on: bool) -> None:
        """Hold (weld) or drop every held object."""
        for eq, *_ in self.held:
            if on and not self.data.eq_active[eq]:
                self._snap_held()
            self.data.eq_active[eq] = int(on)

    def _snap_held(self) -> None:
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

    # ----- stepping ----------------------------------------------------------------------------
    def _update_pins(self, span: float) -> None:
        """Switch the foot pins for a frame of ``span`` s and draw pinned ones after their targets
        (``controller_kernels.switch_pins`` is the compiled copy; the rule is in its docstring)."""
        if not len(self.pin_eq):
            return
        if not self.params.virtual_joints:
            if self.pin_on.any():
                self.pin_on[:] = False
                self.data.eq_active[self.pin_eq] = 0
            return
        prm = self.params
        follow = prm.pin_follow_speed * span
        if prm.compiled:
            d = self.data
            ck.switch_pins(self.p_in, self.v_in, self.pin_point, self._k_pin_rest_z, self.pin_on, self.pin_mocap,
                           d.mocap_pos, d.site_xpos, self._k_site, self.pin_eq, d.eq_active, prm.contact_height,
                           prm.contact_speed, prm.pin_slack, prm.pin_hold, follow)
            return
        pt = self.p_in[self.pin_point]   # the input's: a toe lifted out of the floor swings faster
        vt = self.v_in[self.pin_point]
        # NaN compares False: a missing target is neither low (no pin) nor kept (lets go)
        h = pt[:, 2] - self.pin_rest_z
        vt2 = (vt[:, :2] ** 2).sum(1)
        on = (h <= prm.contact_height) & (vt2 <= prm.contact_speed ** 2) & ~self.pin_on
        if on.any():   # only then where the feet are: a foot far from its target catches up first
            cur = self.point_positions()[self.pin_point]
            on &= ((pt[:, :2] - cur[:, :2]) ** 2).sum(1) <= prm.pin_slack ** 2
        off = np.zeros_like(on)
        if self.pin_on.any():
            anchor = self.data.mocap_pos[self.pin_mocap]
            gap = pt[:, :2] - anchor[:, :2]
            drift2 = (gap ** 2).sum(1)
            keep = (h <= prm.contact_height + 0.01) & (vt2 <= 4 * prm.contact_speed ** 2) & (drift2 <= prm.pin_slack ** 2)
            off = self.pin_on & ~keep
            pull = self.pin_on & keep & (drift2 > prm.pin_hold ** 2)
            if pull.any():
                drift = np.sqrt(drift2[pull])
                g = np.minimum(follow, drift - prm.pin_hold) / drift
                anchor[pull, :2] += g[:, None] * gap[pull]
                self.data.mocap_pos[self.pin_mocap[pull]] = anchor[pull]
        if not (on.any() or off.any()):
            return                    # no pin switched: nothing more to write
        if on.any():
            at = cur[on]
            at[:, 2] = self.pin_rest_z[on]  # on the floor: never hold a foot sunk into it
            self.data.mocap_pos[self.pin_mocap[on]] = at
        self.pin_on = (self.pin_on | on) & ~off
        self.data.eq_active[self.pin_eq] = self.pin_on.astype(np.uint8)

    def _update_dodge(self) -> bool:
        """Figure 4's forearm targets for this frame; True while any is set."""
        if self._dodging:
            self.dodge_override[:] = np.nan
            self._dodging = False
        if not self.params.dodge or not len(self.ball_body):
            return False
        d = self.data
        bp = d.xpos[self.ball_body]
        bv = np.array([d.qvel[a:a + 3] for a in self.ball_dof])
        moving = np.linalg.norm(bv, axis=1) > 1.0
        for k, cb in enumerate(self.bodies):
            ch = cb.character
            try:
                head = ch.index("Head")
            except KeyError:
                continue
            a = self.point_slice[k].start
            hp = self.point_positions()[a + head]
            rel = hp - bp
            speed2 = np.maximum((bv * bv).sum(1), 1e-9)
            t_close = (rel * bv).sum(1) / speed2
            miss = np.linalg.norm(rel - bv * t_close[:, None], axis=1)
            threat = moving & (t_close > 0) & (t_close < self.params.dodge_horizon_s) & (miss < 0.35)
            if threat.any():
                self._dodge_until[k] = d.time + 0.4
                i = int(np.flatnonzero(threat)[np.argmin(t_close[threat])])
                self._dodge_dir = -bv[i] / np.linalg.norm(bv[i])
            if d.time < self._dodge_until[k]:
                self._raise_forearms(k, hp, self._dodge_dir)
                self._dodging = True
        return self._dodging

    def _raise_forearms(self, k: int, head: np.ndarray, towards: np.ndarray) -> None:
        """Figure 4: forearm targets (elbows, wrists, hands) set around the head, facing the ball."""
        ch = self.bodies[k].character
        front = towards.copy()
        front[2] = 0.0
        front /= max(np.linalg.norm(front), 1e-9)
        up = np.array([0.0, 0, 1])
        left = np.cross(up, front)
        a = self.point_slice[k].start
        for side, s in (("Left", 1.0), ("Right", -1.0)):
            spots = {f"Elbow{side}": head + 0.12 * front + s * 0.22 * left - 0.05 * up,
                     f"Wrist{side}": head + 0.22 * front + s * 0.07 * left + 0.06 * up,
                     f"Hand{side}": head + 0.24 * front + s * 0.03 * left + 0.14 * up}
            for jn, p in spots.items():
                if jn in ch.joint_names:
                    self.dodge_override[a + ch.joint_names.index(jn)] = p

    def step(self, duration_s: float) -> None:
        """Advance by ``duration_s`` (rounded to whole substeps, at least one)."""
        m, d = self.model, self.data
        ts = m.opt.timestep
        n = max(1, int(round(duration_s / ts)))
        prof = self.profile
        t = time.thread_time() if prof is not None else 0.0
        self._update_pins(n * ts)
        dodging = self._update_dodge()
        if prof is not None:
            t = tick(prof, "pins, dodge", t)
        if self.params.compiled:
            self._step_compiled(n)
        else:
            self._step_numpy(n, dodging)
        if prof is not None:
            t = time.thread_time()
        if self._pushes:
            self._pushes = [p for p in self._pushes if d.time < p.until]
        self.frames_stepped += 1
        wn, (a, b, c) = self._k_warnings, self._k_bad
        if int(wn[a]) + int(wn[b]) + int(wn[c]) > self._badqacc or not math.isfinite(self._k_qvel.sum()):
            self._recover()
        if prof is not None:
            tick(prof, "checks", t)

    def _step_compiled(self, n: int) -> None:
        """``n`` substeps with the control as kernels writing ``xfrc_applied`` in place."""
        t = time.thread_time() if self.profile is not None else 0.0
        m, d = self.model, self.data
        ts = m.opt.timestep
        g = self.params.gains
        c0, slope, kp, kd, f, tq, tops = (self._k_c0, self._k_slope, self._k_kpf, self._k_kdf, self._k_f,
                                          self._k_tq, self._k_tops)
        ck.frame_terms(self.p_t, self.v_t, self.override, self.dodge_override, self._k_kp, self._k_kd, n * ts, ts,
                       c0, slope, kp, kd)
        site_xpos, cvel, subtree_com, xipos = d.site_xpos, d.cvel, d.subtree_com, d.xipos
        xquat, xmat, xfrc = d.xquat, d.xmat, d.xfrc_applied
        fmax2 = 0.0
        prof = self.profile
        for i in range(n):
            if prof is not None:
                t = tick(prof, "controller", t)
            mujoco.mj_step1(m, d)
            if prof is not None:
                t = tick(prof, "mj_step", t)
            ck.substep_control(site_xpos, cvel, subtree_com, xipos, xquat, xmat, xfrc, self._k_site, self._k_body,
                               self._k_root, self._k_bbody, self._k_baxis, self._k_scale, c0, slope, kp, kd,
                               self._k_bound, self.q_t, self.w_t, self.has_rot, i, g.kp_rot, g.kd_rot,
                               g.max_torque, f, tq, tops)
            fmax2 = max(fmax2, tops[0])
            if self._pushes:
                self._apply_pushes()
            if prof is not None:
                t = tick(prof, "controller", t)
            mujoco.mj_step2(m, d)
            if prof is not None:
                t = tick(prof, "mj_step", t)
        self.max_applied_force = max(self.max_applied_force, math.sqrt(fmax2))
        self.max_applied_torque = max(self.max_applied_torque, float(tops[1]))
        self.last_forces, self.last_torques = f.copy(), tq.copy()   # the kernels' buffers change next step

    def _apply_pushes(self) -> None:
        """Active pushes added to ``xfrc_applied`` at their points (after the bounded control)."""
        d = self.data
        for push in self._pushes:
            if d.time < push.until:
                b = self.pt_body[push.point]
                arm = d.site_xpos[self.pt_site[push.point]] - d.xipos[b]
                d.xfrc_applied[b, :3] += push.force
                d.xfrc_applied[b, 3:] += np.cross(arm, push.force)

    def _step_numpy(self, n: int, dodging: bool) -> None:
        """The numpy reference of the control substeps (``controller_kernels``)."""
        t0 = time.thread_time() if self.profile is not None else 0.0
        m, d = self.model, self.data
        ts = m.opt.timestep
        g = self.params.gains
        vel = self.v_t
        if self._has_override or dodging:
            fixed = np.isfinite(self.override) | np.isfinite(self.dodge_override)
            target = np.where(np.isfinite(self.override), self.override, self.p_t)
            target = np.where(np.isfinite(self.dodge_override), self.dodge_override, target)
            vel = np.where(fixed, 0.0, vel)   # a positional constraint holds still
        else:
            target = self.p_t
        has_t = np.isfinite(target).all(1)
        # per frame, not per substep: a point without a target gets zero gains (so no force) and
        # finite zeros for its target, which is what masking the NaN force after the fact gave
        if has_t.all():
            kp, kd = self._kp, self._kd
        else:
            mask = has_t[:, None]
            kp, kd = self._kp * mask, self._kd * mask
            target = np.where(mask, target, 0.0)
            vel = np.where(mask, vel, 0.0)
        # Eq 1 is f = Ke (p_t - p) + Kd (v_t - v) with targets moving on between frames at their
        # velocity (the input arrives per frame): f = c0 + (i + 1) slope - Ke p - Kd v at substep i
        c0 = kp * (target - vel * (n * ts)) + kd * vel
        slope = kp * vel * ts
        site, pt, root = self.pt_site, self.pt_body, self.pt_root
        npt = len(pt)
        W = self._wrench
        A = self._A
        fmax2 = 0.0
        bound2 = self._bound2
        prof = self.profile
        t = t0
        for i in range(n):
            if prof is not None:
                t = tick(prof, "controller", t)
            mujoco.mj_step1(m, d)
            if prof is not None:
                t = tick(prof, "mj_step", t)
            p = d.site_xpos[site]
            cv = d.cvel[pt]
            v = cv[:, 3:] + cross(cv[:, :3], p - d.subtree_com[root])
            f = (c0 + slope * (i + 1)) - kp * p - kd * v   # Eq 1 (joint_forces, gains premultiplied)
            norm2 = (f * f).sum(1)
            top2 = float(norm2.max())              # NaN if any is: one reduction checks both
            if not math.isfinite(top2):            # a blown-up state: no force from it
                f = np.where(np.isfinite(f), f, 0.0)
                norm2 = (f * f).sum(1)
                top2 = float(norm2.max())
            if (norm2 > bound2).any():             # clip_norm, skipped when nothing is over its bound
                f *= np.minimum(1.0, self.force_bound / np.sqrt(np.maximum(norm2, 1e-24)))[:, None]
                top2 = float((f * f).sum(1).max())
            fmax2 = max(fmax2, top2)
            if i == 0:
                # Eq 2 once per frame, held over its substeps: gains per unit inertia keep
                # Kd_rot * frame span well inside the stable range, and it halves the work
                b = self._b_rows
                axis = (d.xmat[b].reshape(-1, 3, 3) @ self._b_axis_col)[:, :, 0]
                tq = twist_torques(g, d.xquat[b], d.cvel[b, :3], axis, self.q_t, self.w_t,
                                   self.scale_body) * self._has_rot_col
                self.max_applied_torque = max(self.max_applied_torque, float(np.sqrt((tq * tq).sum(1).max(initial=0.0))))
                # what each body gets besides the joint forces, the same every substep (gravity
                # compensation is MuJoCo's gravcomp)
                W[npt:] = 0.0
                W[npt + self.b_body, 3:] = tq
            arm = p - d.xipos[pt]
            W[:npt, :3] = f
            W[:npt, 3:] = cross(arm, f)
            if self._pushes:
                for push in self._pushes:
                    if d.time < push.until:
                        W[push.point, :3] += push.force
                        W[push.point, 3:] += np.cross(arm[push.point], push.force)
            if self._A_sparse is None:
                np.matmul(A, W, out=d.xfrc_applied)
            else:
                d.xfrc_applied[:] = self._A_sparse @ W
            if prof is not None:
                t = tick(prof, "controller", t)
            mujoco.mj_step2(m, d)
            if prof is not None:
                t = tick(prof, "mj_step", t)
        self.max_applied_force = max(self.max_applied_force, math.sqrt(fmax2))
        self.last_forces, self.last_torques = f, tq

    _badqacc = 0

    def _recover(self) -> None:
        """The state blew up (MuJoCo reset it or it went NaN): put each character on its target."""
        self.resets += 1
        keep = self.data.warning.number.copy()
        now = float(self.data.time)
        self._badqacc = int(keep[self._bad_warnings].sum())
        mujoco.mj_resetData(self.model, self.data)
        self.data.warning.number[:] = keep
        self.data.time = now   # the clock goes on (pushes, the dodge and the node's status run on it)
        mujoco.mj_forward(self.model, self.data)

    # ----- outputs -----------------------------------------------------------------------------
    def tracking_error(self) -> np.ndarray:
        """Per stacked joint: distance from the simulated joint to its target, m (NaN: no target)."""
        if self.params.compiled:
            self.geom_state()
            return self._k_point_err.copy()
        target = np.where(np.isfinite(self.override), self.override, self.p_t)
        return np.linalg.norm(self.point_positions() - target, axis=1)

    def geom_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Published geoms: positions [G, 3] m, orientations [G, 4] wxyz, tracking error [G] m."""
        d = self.data
        if self.params.compiled:
            G = len(self.geom_ids)
            pos, quat, err = np.empty((G, 3)), np.empty((G, 4)), np.empty(G)
            sk.geom_state_into(d.geom_xpos, d.geom_xmat, self._k_geoms, d.site_xpos, self._k_site, self.p_t,
                               self.override, self._k_gj0, self._k_gj1, self._k_point_err, pos, quat, err)
            return pos, quat, err
        pos = d.geom_xpos[self.geom_ids].copy()
        quat = matrix_to_quat(d.geom_xmat[self.geom_ids].reshape(-1, 3, 3))
        err = np.full(len(self.geom_ids), np.nan)
        mine = self.geom_joints[:, 0] >= 0
        e = self.tracking_error()
        err[mine] = 0.5 * (e[self.geom_joints[mine, 0]] + e[self.geom_joints[mine, 1]])
        return pos, quat, err

    def geom_shapes(self) -> tuple[tuple[str, ...], np.ndarray]:
        """Shape names and MuJoCo sizes [G, 3] of the published geoms."""
        names = {mujoco.mjtGeom.mjGEOM_BOX: "box", mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
                 mujoco.mjtGeom.mjGEOM_CAPSULE: "capsule", mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder"}
        shapes = tuple(names.get(int(t), "mesh") for t in self.model.geom_type[self.geom_ids])
        return shapes, self.model.geom_size[self.geom_ids].copy()


def _clip_rows(v: np.ndarray, limit: float) -> np.ndarray:
    """``clip_norm`` of finite rows [N, 3], skipping the work when none is over ``limit``."""
    n2 = (v * v).sum(1)
    if n2.max(initial=0.0) <= limit * limit:
        return v
    return v * np.minimum(1.0, limit / np.sqrt(np.maximum(n2, 1e-24)))[:, None]


def lift_above_floor(p: np.ndarray, parents: np.ndarray, min_z: np.ndarray) -> np.ndarray:
    """Targets [J, 3] with every joint at least ``min_z`` [J] high: a joint below it swings up
    about its parent's target (bone length kept, heading kept), or is raised if that cannot reach."""
    low = p[:, 2] < min_z
    if not low.any():
        return p
    out = p.copy()
    par = np.maximum(parents, 0)
    d = p - p[par]
    L = np.sqrt((d * d).sum(1))
    dz = min_z - p[par, 2]
    hz = np.sqrt((d[:, :2] ** 2).sum(1))
    can = low & (parents >= 0) & (np.abs(dz) < L) & (hz > 1e-9)
    h = np.sqrt(np.maximum(L ** 2 - dz ** 2, 0.0)) / np.maximum(hz, 1e-9)
    swung = np.concatenate([p[par, :2] + d[:, :2] * h[:, None], (p[par, 2] + dz)[:, None]], axis=1)
    out[can] = swung[can]
    out[:, 2] = np.maximum(out[:, 2], min_z)
    return out


def build_xml(bodies: list[CharacterBody], stage: Stage, params: TrackerParams) -> str:
    """The MJCF of a world: floor, characters, their foot pins, the stage, held-object welds."""
    root, worldbody, equality = world_root(params.timestep, floor_friction=stage.floor_friction)
    for cb in bodies:
        add_character(worldbody, cb, len(bodies), params.joint_damping, gravcomp=params.gravity_compensation)
    for cb in bodies:
        add_pins(worldbody, equality, cb)
    add_stage(worldbody, stage)
    for o in stage.objects:
        if o.held_by is None or o.held_by[0] >= len(bodies):
            continue
        cb = bodies[o.held_by[0]]
        try:
            j = cb.character.index(o.held_by[1])
        except KeyError as exc:
            raise ValueError(f"stage {stage.source or stage.name}: object {o.name}: held_by: {exc.args[0]}") from None
        b = int(cb.body_joints[cb.joint_body[j]])
        # spawn the object at the hand in the rest pose, handle along the world's forward axis
        pos, _ = cb.character.rest_pose()
        obj = worldbody.find(f"body[@name='stage/{o.name}']")
        obj.set("pos", fmt(pos[j] + cb.spawn))
        obj.set("quat", fmt([np.sqrt(0.5), 0, np.sqrt(0.5), 0]))  # body z -> world x
        ET.SubElement(equality, "weld", name=f"hold/{o.name}", body1=cb.body_name(b), body2=f"stage/{o.name}",
                      solref="0.005 1")
    return to_xml(root)
