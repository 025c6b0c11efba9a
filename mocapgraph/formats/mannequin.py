"""A generated mannequin: a smooth skinned body built from a character's own bones, linear-blend weights.

Every bone (a joint and its parent, longer than 1 cm) gets a capsule around it: a tube of
``SEGMENTS`` sides from the parent joint to the joint, closed by half-spheres, its radius from the
bone's length and place (the trunk, bones with both ends within 9 % of the standing height of the
midline and above the hips: pelvis, spine, neck, head, 5 % of the height; limbs 14 % of their length, within 1.5-6 cm). A capsule moves with the
parent joint (the bone's own rotation); near its ends its vertices blend linearly into the
neighbouring bones (the grandparent's at the base, the child joint's at the tip), so elbows and
knees bend smoothly instead of tearing. Everything is built once per character, vectorised over
bones. :func:`mannequin` returns a :class:`mocapgraph.formats.gltf_export.SkinnedMesh` in the
world frame of the rest pose; the glTF writer binds it with the inverse bind matrices of the rest
pose, so any viewer skinning it (three.js, Blender, Unity) shows the body following the animation.
"""
from __future__ import annotations

import numpy as np

from ..retarget.character import Character
from .gltf_export import SkinnedMesh

SEGMENTS = 10          # sides of each tube
RINGS = 6              # rings along the tube (blend zones at both ends)
CAP_RINGS = 3          # rings of each half-sphere
MIN_BONE_M = 0.01
BLEND = 0.25           # fraction of a bone's length at each end where it blends into its neighbour


def _template() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A unit capsule along +Z from 0 to 1: (unit radial directions [V, 3], axial parameter s [V],
    cap offsets along the axis in radii [V], triangles [T, 3])."""
    ang = 2 * np.pi * np.arange(SEGMENTS) / SEGMENTS
    circle = np.stack([np.cos(ang), np.sin(ang), np.zeros(SEGMENTS)], axis=1)
    rows = []   # (s, cap axial offset in radii, radial scale)
    for k in range(CAP_RINGS, 0, -1):           # base half-sphere, pole excluded
        phi = np.pi / 2 * k / (CAP_RINGS + 1)
        rows.append((0.0, -np.sin(phi), np.cos(phi)))
    for s in np.linspace(0.0, 1.0, RINGS):
        rows.append((float(s), 0.0, 1.0))
    for k in range(1, CAP_RINGS + 1):           # tip half-sphere
        phi = np.pi / 2 * k / (CAP_RINGS + 1)
        rows.append((1.0, np.sin(phi), np.cos(phi)))
    rows_a = np.array(rows)
    n_rows = len(rows_a)
    radial = (circle[None] * rows_a[:, None, 2:3]).reshape(-1, 3)
    s = np.repeat(rows_a[:, 0], SEGMENTS)
    cap = np.repeat(rows_a[:, 1], SEGMENTS)
    # the two poles
    radial = np.vstack([radial, [[0, 0, 0], [0, 0, 0]]])
    s = np.r_[s, 0.0, 1.0]
    cap = np.r_[cap, -1.0, 1.0]
    ring = np.arange(n_rows - 1)[:, None] * SEGMENTS
    a = ring + np.arange(SEGMENTS)[None]
    b = ring + (np.arange(SEGMENTS)[None] + 1) % SEGMENTS
    quads = np.stack([a, b, b + SEGMENTS, a, b + SEGMENTS, a + SEGMENTS], axis=-1).reshape(-1, 3)
    base, tip = n_rows * SEGMENTS, n_rows * SEGMENTS + 1
    seg = np.arange(SEGMENTS)
    nxt = (seg + 1) % SEGMENTS
    last = (n_rows - 1) * SEGMENTS
    caps = np.concatenate([np.stack([np.full(SEGMENTS, base), nxt, seg], axis=1),
                           np.stack([np.full(SEGMENTS, tip), last + seg, last + nxt], axis=1)])
    return radial, s, cap, np.concatenate([quads, caps])


def _frames(d: np.ndarray) -> np.ndarray:
    """Rotations [B, 3, 3] taking +Z onto the unit directions d [B, 3]."""
    z = d
    helper = np.where(np.abs(z[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=2)


def bone_radii(ch: Character, lengths: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Capsule radius per bone (ending at ``joints``), m: limbs 14 % of their length within
    1.5-6 cm; the trunk (both ends near the midline, the body facing +X) 5 % of the height."""
    p0, _ = ch.rest_pose()
    height = max(float(np.ptp(p0[:, 2])), 0.3)
    side = np.abs(p0[:, 1] - p0[ch.root, 1])
    above = p0[:, 2] > p0[ch.root, 2] - 0.05 * height        # not the legs
    near = (side < 0.09 * height) & above
    trunk = near[joints] & near[ch.parents[joints]]
    return np.where(trunk, 0.05 * height, np.clip(0.14 * lengths, 0.015, 0.06))


def mannequin(ch: Character, name: str = "mannequin") -> SkinnedMesh:
    """The character's mannequin at its rest pose (see the module docstring)."""
    p0, _ = ch.rest_pose()
    par = ch.parents
    j = np.flatnonzero(par >= 0)
    vec = p0[j] - p0[par[j]]
    length = np.linalg.norm(vec, axis=1)
    keep = length >= MIN_BONE_M
    j, vec, length = j[keep], vec[keep], length[keep]
    if not len(j):
        raise ValueError(f"{ch.name}: no bone of {MIN_BONE_M * 100:g} cm or more to build a mannequin on")
    p = par[j]
    radius = bone_radii(ch, length, j)
    radial, s, cap, tri = _template()
    rot = _frames(vec / length[:, None])                              # [B, 3, 3]
    local = (radial[None] * radius[:, None, None]
             + np.stack([np.zeros_like(s), np.zeros_like(s), s], 1)[None] * length[:, None, None]
             + np.stack([np.zeros_like(cap), np.zeros_like(cap), cap], 1)[None] * radius[:, None, None])
    pos = p0[p][:, None] + np.einsum("bij,bvj->bvi", rot, local)      # [B, V, 3]
    nrm_local = radial + np.stack([np.zeros_like(cap), np.zeros_like(cap), cap], 1)
    nrm = np.einsum("bij,bvj->bvi", rot, np.broadcast_to(nrm_local, pos.shape))
    nrm /= np.linalg.norm(nrm, axis=-1, keepdims=True)
    # weights: the bone's driver (the parent joint p) and, within BLEND of an end, the neighbour
    grand = np.where(par[p] >= 0, par[p], p)
    w_base = np.clip(0.5 * (1 - s / BLEND), 0, 0.5)[None] * (grand != p)[:, None]
    w_tip = np.clip(0.5 * (s - (1 - BLEND)) / BLEND, 0, 0.5)[None].repeat(len(j), 0)
    has_kids = np.isin(j, par)                                        # a leaf's tip has nothing to bend into
    w_tip = w_tip * has_kids[:, None]
    w_self = 1.0 - w_base - w_tip
    B, V = pos.shape[:2]
    joints = np.stack([np.repeat(p[:, None], V, 1), np.repeat(grand[:, None], V, 1),
                       np.repeat(j[:, None], V, 1), np.zeros((B, V), np.int64)], axis=-1)
    weights = np.stack([w_self, w_base, w_tip, np.zeros((B, V))], axis=-1)
    triangles = (tri[None] + (np.arange(B) * V)[:, None, None]).reshape(-1, 3)
    return SkinnedMesh(pos.reshape(-1, 3), nrm.reshape(-1, 3), triangles, joints.reshape(-1, 4),
                       weights.reshape(-1, 4), name=name)
