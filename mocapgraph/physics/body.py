"""A character's physical body as MJCF: a capsule per bone, de Leva masses, ball joints.

Frames: one MuJoCo body per character joint that has children, its frame at the joint and oriented
as the joint (``W[j]`` of the character's forward kinematics), attached to the body of its parent
joint by a ball joint at its origin (the root by a free joint). So a ball joint's ``qpos`` is the
character's local rotation of that joint and the free joint's is (root position, ``rest · local``)
of the root: no conversion between ``CharacterPose`` and ``mjData``. Every bone ``p -> c`` is a
capsule on body ``p`` from its origin to ``rest_offsets[c]``. Joints without children (hands,
feet, head) are points on their parent's body. Masses and inertias follow
:mod:`anthropometry` (de Leva 1996), scaled to the body mass.

Collision: a character's own capsules never collide with each other (Shum & Ho's ODE character
has no self-collision either); they collide with the floor, the stage and other characters.
Each character gets its own contype bit (bit ``1 + k``), so at most 30 characters share a world.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from ..retarget.character import Character
from .anthropometry import bone_masses

MAX_CHARACTERS = 30
# Character contacts with direct stiffness and damping (N/m per unit effective mass, negative form):
# MuJoCo's default time-constant contacts let a light foot under the body's weight sink 2-3 cm;
# these hold it to a few mm (benchmarked in tests/physics). solmix makes them win over the floor's,
# and MuJoCo takes the element-wise minimum of two direct solrefs, so they also set every contact
# with a stage object. The damping times the 1/240 s timestep stays at 1: the solver removes an
# approach speed within one step and no more (650 overshot to -1.7 times it, a restitution above 1:
# a foot meeting the pole's 1.5 kg cube at 4 m/s, 11 mm deep in one step, threw it at 7.9 m/s).
CONTACT_SOLREF = "-100000 -240"
WORLD_BIT = 1


def fmt(v) -> str:
    """Numbers as MJCF text (short, exact enough)."""
    return " ".join(f"{float(x):.9g}" for x in np.ravel(v))


@dataclass(frozen=True, eq=False)
class CharacterBody:
    """How one character sits in a world: names, which body carries each joint, points, axes."""

    character: Character
    prefix: str                 # MuJoCo name prefix, e.g. "c0/"
    index: int                  # character number in the world (contype bit 1 + index)
    body_mass: float            # kg
    body_joints: np.ndarray     # int [B] character joints that own a MuJoCo body
    joint_body: np.ndarray      # int [J] index into body_joints of the body a joint's force acts on
    joint_point: np.ndarray     # [J, 3] m, the joint in that body's frame
    twist_axis: np.ndarray      # [B, 3] unit bone axis of each body, body frame (Eq 2 axis)
    bone_child: np.ndarray      # int [G] child joint of each bone capsule (geom order)
    bone_radius: np.ndarray     # [G] m
    feet: np.ndarray            # int [F] leaf joints of the foot class (virtual-joint pins)
    hands: np.ndarray           # int [H] leaf joints of the hand class (held objects)
    spawn: np.ndarray           # [3] m, world offset of the whole character at its rest pose

    def body_name(self, joint: int) -> str:
        return f"{self.prefix}{self.character.joint_names[joint]}"

    def geom_name(self, child: int) -> str:
        p = int(self.character.parents[child])
        names = self.character.joint_names
        return f"{self.prefix}{names[p]}-{names[child]}"

    def site_name(self, joint: int) -> str:
        return f"{self.prefix}at/{self.character.joint_names[joint]}"

    def pin_name(self, joint: int) -> str:
        return f"{self.prefix}pin/{self.character.joint_names[joint]}"

    @property
    def standing_height(self) -> float:
        """Rest height of the root above the floor, m."""
        pos, _ = self.character.rest_pose()
        return float(pos[self.character.root, 2] + self.spawn[2])


def leaf_of_class(character: Character, classes: tuple[str, ...], cls: str) -> np.ndarray:
    has_child = np.zeros(character.n_joints, dtype=bool)
    has_child[character.parents[character.parents >= 0]] = True
    return np.array([j for j in range(character.n_joints) if classes[j] == cls and not has_child[j]],
                    dtype=np.int64)


def character_body(character: Character, index: int, body_mass: float = 70.0,
                   spawn: np.ndarray | None = None) -> CharacterBody:
    """Plan the MuJoCo bodies of ``character`` (number ``index`` in its world)."""
    if not 0 <= index < MAX_CHARACTERS:
        raise ValueError(f"at most {MAX_CHARACTERS} characters share a world (got number {index})")
    n = character.n_joints
    par = character.parents
    has_child = np.zeros(n, dtype=bool)
    has_child[par[par >= 0]] = True
    body_joints = np.flatnonzero(has_child)
    slot = -np.ones(n, dtype=np.int64)
    slot[body_joints] = np.arange(len(body_joints))
    joint_body = np.where(has_child, slot, slot[np.maximum(par, 0)])
    if character.root not in body_joints:
        raise ValueError(f"character {character.name!r}: the root has no children, nothing to simulate")
    joint_point = np.where(has_child[:, None], 0.0, character.rest_offsets)
    axes = np.zeros((len(body_joints), 3))
    for b, j in enumerate(body_joints):
        kids = character.children(j)
        # the twist axis: along the one child's bone, or the sum of several (the pelvis's and the
        # upper trunk's side bones cancel, leaving the spine)
        d = character.rest_offsets[kids]
        v = d.sum(axis=0)
        if np.linalg.norm(v) < 1e-6:
            v = d[0]
        axes[b] = v / np.linalg.norm(v)
    bm = bone_masses(character, body_mass)
    bones = np.flatnonzero(par >= 0)
    pos, _ = character.rest_pose()
    spawn = np.zeros(3) if spawn is None else np.asarray(spawn, float)
    z = pos[:, 2] + spawn[2]
    # no capsule reaches below the floor at rest (feet: the ball of the foot sits near z = 0)
    radius = np.minimum(bm.radius[bones], np.maximum(np.minimum(z[bones], z[par[bones]]), 0.005))
    return CharacterBody(character, f"c{index}/", index, float(body_mass), body_joints, joint_body,
                         joint_point, axes, bones, radius, leaf_of_class(character, bm.classes, "foot"),
                         leaf_of_class(character, bm.classes, "hand"), spawn)


def body_inertia(cb: CharacterBody) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per body: mass [B] kg, centre of mass [B, 3] and full inertia [B, 3, 3] about it, body frame."""
    ch = cb.character
    bm = bone_masses(ch, cb.body_mass)
    B = len(cb.body_joints)
    mass = np.zeros(B)
    com = np.zeros((B, 3))
    inertia = np.zeros((B, 3, 3))
    slot = {int(j): b for b, j in enumerate(cb.body_joints)}
    parts: list[list[tuple[float, np.ndarray, np.ndarray]]] = [[] for _ in range(B)]
    for c in cb.bone_child:
        b = slot[int(ch.parents[c])]
        off = ch.rest_offsets[c]
        L = np.linalg.norm(off)
        u = off / L
        # a frame with z along the bone
        t = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
        t /= np.linalg.norm(t)
        R = np.stack([t, np.cross(u, t), u], axis=1)
        m = bm.mass[c]
        Ic = R @ np.diag(m * bm.gyration[c] ** 2) @ R.T
        parts[b].append((m, off * bm.com_frac[c], Ic))
    for b in range(B):
        m = sum(p[0] for p in parts[b])
        c = sum(p[0] * p[1] for p in parts[b]) / m
        I = np.zeros((3, 3))
        for mi, ci, Ii in parts[b]:
            d = ci - c
            I += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))  # parallel axes
        mass[b], com[b], inertia[b] = m, c, I + np.eye(3) * 1e-6
    return mass, com, inertia


def add_character(worldbody: ET.Element, cb: CharacterBody, n_characters: int,
                  joint_damping: float = 1.0, friction: float = 1.0, gravcomp: float = 0.0) -> None:
    """Append ``cb``'s bodies to ``worldbody`` (its pins' mocap bodies: :func:`add_pins`).

    Every character joint gets a site at its point (``site_name``), where Eq 1 acts; ``gravcomp``
    is the fraction of each body's weight MuJoCo holds up at its centre of mass."""
    ch = cb.character
    mass, com, inertia = body_inertia(cb)
    slot = {int(j): b for b, j in enumerate(cb.body_joints)}
    own = 1 << (1 + cb.index)
    others = sum(1 << (1 + k) for k in range(n_characters) if k != cb.index)
    elems: dict[int, ET.Element] = {}
    for j in cb.body_joints:  # parents first
        j = int(j)
        p = int(ch.parents[j])
        parent = worldbody if p < 0 else elems[p]
        pos = ch.rest_offsets[j] + (cb.spawn if p < 0 else 0.0)
        el = ET.SubElement(parent, "body", name=cb.body_name(j), pos=fmt(pos), quat=fmt(ch.rest_rotations[j]))
        if gravcomp:
            el.set("gravcomp", fmt(gravcomp))
        if p < 0:
            ET.SubElement(el, "freejoint", name=f"{cb.prefix}root")
        else:
            ET.SubElement(el, "joint", name=f"{cb.prefix}{ch.joint_names[j]}", type="ball",
                          damping=fmt(joint_damping))
        b = slot[j]
        I = inertia[b]
        ET.SubElement(el, "inertial", pos=fmt(com[b]), mass=fmt(mass[b]),
                      fullinertia=fmt([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]))
        elems[j] = el
    for g, c in enumerate(cb.bone_child):
        p = int(ch.parents[c])
        ET.SubElement(elems[p], "geom", name=cb.geom_name(int(c)), type="capsule",
                      fromto=fmt(np.r_[np.zeros(3), ch.rest_offsets[c]]), size=fmt(cb.bone_radius[g]),
                      contype=str(own), conaffinity=str(WORLD_BIT | others), friction=fmt([friction, 0.005, 0.0001]),
                      rgba="0.3 0.75 0.75 1", mass="0", solref=CONTACT_SOLREF, solimp="0.99 0.999 0.001", solmix="1000")
    for j in range(ch.n_joints):
        ET.SubElement(elems[int(cb.body_joints[cb.joint_body[j]])], "site", name=cb.site_name(j),
                      pos=fmt(cb.joint_point[j]), size="0.01", group="5")


def add_pins(worldbody: ET.Element, equality: ET.Element, cb: CharacterBody) -> None:
    """Virtual ball joints (inactive) fixing each foot point to its mocap pin (Shum & Ho 6.1), and
    the pins' mocap bodies (added after every character's bodies keep each character's body ids
    one contiguous range)."""
    pos, _ = cb.character.rest_pose()
    for f in cb.feet:
        ET.SubElement(worldbody, "body", name=cb.pin_name(int(f)), mocap="true", pos=fmt(pos[f] + cb.spawn))
    for f in cb.feet:
        f = int(f)
        body = cb.body_name(int(cb.body_joints[cb.joint_body[f]]))
        ET.SubElement(equality, "connect", name=f"{cb.prefix}pin/{cb.character.joint_names[f]}", body1=body,
                      body2=cb.pin_name(f), anchor=fmt(cb.joint_point[f]), active="false",
                      solref="0.01 1")


def world_root(timestep: float, model_name: str = "mocapgraph", floor_friction: float = 1.0
               ) -> tuple[ET.Element, ET.Element, ET.Element]:
    """An empty world (root, worldbody, equality): floor plane, gravity, options."""
    root = ET.Element("mujoco", model=model_name)
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(root, "option", timestep=fmt(timestep), gravity="0 0 -9.81", integrator="implicitfast")
    vis = ET.SubElement(root, "visual")
    ET.SubElement(vis, "global", offwidth="640", offheight="480")
    asset = ET.SubElement(root, "asset")
    ET.SubElement(asset, "texture", name="grid", type="2d", builtin="checker", rgb1=".2 .3 .4",
                  rgb2=".1 .15 .2", width="512", height="512")
    ET.SubElement(asset, "material", name="grid", texture="grid", texrepeat="8 8", reflectance=".1")
    worldbody = ET.SubElement(root, "worldbody")
    ET.SubElement(worldbody, "light", pos="0 0 4", dir="0 0 -1", directional="true")
    ET.SubElement(worldbody, "geom", name="floor", type="plane", size="0 0 0.05", material="grid",
                  contype=str(WORLD_BIT), conaffinity=str((1 << (MAX_CHARACTERS + 1)) - 1),
                  friction=fmt([floor_friction, 0.005, 0.0001]))
    equality = ET.SubElement(root, "equality")
    return root, worldbody, equality


def to_xml(root: ET.Element) -> str:
    ET.indent(root)
    return ET.tostring(root, encoding="unicode")
