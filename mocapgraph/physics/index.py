"""Names to ids of a built physics world: every character's joint points, bodies, pins and geoms.

One :class:`WorldIndex` per MuJoCo model, built once by :func:`index_world` from the model and the
:class:`~.body.CharacterBody` descriptions it was built from. Joint points and controlled bodies are
stacked over the characters (character ``k``'s rows are ``point_slice[k]`` / ``body_slice[k]``);
every id array is C-contiguous int64, ready for the kernels. Frames: world Z up; m.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .body import CharacterBody
from .stage import Stage


@dataclass
class WorldIndex:
    """Ids of everything the parts of a world address (see the module docstring)."""

    point_slice: list[slice]     # per character: its rows of the stacked points
    body_slice: list[slice]      # per character: its rows of the stacked bodies
    qpos_adr: list[np.ndarray]   # per character: qpos address of each body's joint (body order)
    pt_body: np.ndarray          # [N] body of each joint point
    pt_site: np.ndarray          # [N] its site (where the point is)
    pt_root: np.ndarray          # [N] its body's root body
    pt_char: np.ndarray          # [N] its character
    pt_min_z: np.ndarray         # [N] m, lowest target height (the radius of its capsules)
    b_body: np.ndarray           # [B] controlled bodies
    b_axis: np.ndarray           # [B, 3] their twist (bone) axes, body frame
    b_joint: np.ndarray          # [B] the joint each body is
    pin_eq: np.ndarray           # [P] foot pins: connect equality ids
    pin_mocap: np.ndarray        # [P] their mocap bodies
    pin_point: np.ndarray        # [P] their stacked foot points
    pin_rest_z: np.ndarray       # [P] m, the feet's rest heights
    geom_ids: np.ndarray         # [G] published geoms: every character capsule and stage geom, not the floor
    geom_names: tuple[str, ...]  # [G]
    geom_joints: np.ndarray      # [G, 2] a character capsule's two stacked points, -1: not a capsule
    char_capsules: list[np.ndarray]   # per character: its capsules' geom ids
    joints: list[np.ndarray]     # per character: the joint of each body (int64)
    parents: list[np.ndarray]    # per character: joint parents (int64)
    ball_joint: list[int]        # per shooter ball: qpos address of its free joint
    ball_dof: list[int]          # per ball: its dof address
    ball_body: np.ndarray        # [balls] body ids

    @property
    def pin_char(self) -> np.ndarray:
        """[P] the character of each pin."""
        return self.pt_char[self.pin_point]

    def point(self, k: int, joint: int) -> int:
        """Stacked point of joint ``joint`` of character ``k``."""
        return self.point_slice[k].start + int(joint)


def _id(m: mujoco.MjModel, kind: mujoco.mjtObj, name: str) -> int:
    return mujoco.mj_name2id(m, kind, name)


def _characters(m: mujoco.MjModel, bodies: list[CharacterBody]) -> dict:
    """The stacked points and bodies of every character and their pins."""
    BODY = mujoco.mjtObj.mjOBJ_BODY
    out = dict(point_slice=[], body_slice=[], qpos_adr=[], pt_body=[], pt_char=[], b_body=[], b_axis=[],
               b_joint=[], pin_eq=[], pin_mocap=[], pin_point=[], pin_rest_z=[])
    for k, cb in enumerate(bodies):
        bid = np.array([_id(m, BODY, cb.body_name(int(j))) for j in cb.body_joints])
        a = len(out["pt_body"])
        out["pt_body"] += list(bid[cb.joint_body])
        out["pt_char"] += [k] * cb.character.n_joints
        out["point_slice"].append(slice(a, len(out["pt_body"])))
        b0 = len(out["b_body"])
        out["b_body"] += list(bid)
        out["b_axis"] += list(cb.twist_axis)
        out["b_joint"] += list(cb.body_joints)
        out["body_slice"].append(slice(b0, len(out["b_body"])))
        out["qpos_adr"].append(m.jnt_qposadr[m.body_jntadr[bid]])
        rest, _ = cb.character.rest_pose()
        for f in cb.feet:
            out["pin_eq"].append(_id(m, mujoco.mjtObj.mjOBJ_EQUALITY, f"{cb.prefix}pin/{cb.character.joint_names[f]}"))
            out["pin_mocap"].append(m.body_mocapid[_id(m, BODY, cb.pin_name(int(f)))])
            out["pin_point"].append(a + int(f))
            out["pin_rest_z"].append(rest[f, 2] + cb.spawn[2])
    return out


def _min_z(bodies: list[CharacterBody], point_slice: list[slice], n: int) -> np.ndarray:
    """[N] m: each point's lowest target height, the largest radius of the capsules meeting at it."""
    min_z = np.zeros(n)
    for k, cb in enumerate(bodies):
        a = point_slice[k].start
        for c, r in zip(cb.bone_child, cb.bone_radius):
            for j in (int(c), int(cb.character.parents[c])):
                min_z[a + j] = max(min_z[a + j], r)
    return min_z


def _geoms(m: mujoco.MjModel, bodies: list[CharacterBody], point_slice: list[slice]) -> dict:
    """The published geoms, each capsule's two joints, and each character's capsules."""
    floor = _id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
    geom_ids = np.array([g for g in range(m.ngeom) if g != floor], dtype=np.int64)
    names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in geom_ids)
    geom_joints = -np.ones((len(geom_ids), 2), dtype=np.int64)
    lookup = {n_: i for i, n_ in enumerate(names)}
    for k, cb in enumerate(bodies):
        a = point_slice[k].start
        for c in cb.bone_child:
            geom_joints[lookup[cb.geom_name(int(c))]] = (a + int(cb.character.parents[c]), a + int(c))
    capsules = [np.array([geom_ids[lookup[cb.geom_name(int(c))]] for c in cb.bone_child], dtype=np.int64)
                for cb in bodies]
    return dict(geom_ids=geom_ids, geom_names=names, geom_joints=geom_joints, char_capsules=capsules)


def index_world(m: mujoco.MjModel, bodies: list[CharacterBody], stage: Stage) -> WorldIndex:
    """The index of model ``m``, built from ``bodies`` on ``stage``."""
    i8 = lambda v: np.ascontiguousarray(v, dtype=np.int64)    # noqa: E731
    c = _characters(m, bodies)
    pt_body = i8(c["pt_body"])
    pt_site = i8([_id(m, mujoco.mjtObj.mjOBJ_SITE, cb.site_name(j)) for cb in bodies
                  for j in range(cb.character.n_joints)])
    b_body = i8(c["b_body"])
    balls = [m.body_jntadr[_id(m, mujoco.mjtObj.mjOBJ_BODY, b)] for b in stage.ball_names]
    return WorldIndex(
        point_slice=c["point_slice"], body_slice=c["body_slice"], qpos_adr=c["qpos_adr"],
        pt_body=pt_body, pt_site=pt_site, pt_root=i8(m.body_rootid[pt_body]), pt_char=np.array(c["pt_char"]),
        pt_min_z=_min_z(bodies, c["point_slice"], len(pt_body)),
        b_body=b_body, b_axis=np.ascontiguousarray(c["b_axis"], dtype=np.float64), b_joint=np.array(c["b_joint"]),
        pin_eq=i8(c["pin_eq"]), pin_mocap=i8(c["pin_mocap"]), pin_point=i8(c["pin_point"]),
        pin_rest_z=np.ascontiguousarray(c["pin_rest_z"], dtype=np.float64),
        **_geoms(m, bodies, c["point_slice"]),
        joints=[i8(cb.body_joints) for cb in bodies], parents=[i8(cb.character.parents) for cb in bodies],
        ball_joint=[m.jnt_qposadr[j] for j in balls], ball_dof=[m.jnt_dofadr[j] for j in balls],
        ball_body=i8([_id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in stage.ball_names]))
