"""Helpers shared by the avatar-output tests (VMC, glTF/VRM): a VMC bundle read back as Unity would
move a humanoid, and a VRM avatar written by the tests themselves (no third-party model files)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pygltflib
from pythonosc.osc_bundle import OscBundle
from scipy.spatial.transform import Rotation

from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.gltf_export import write_gltf
from mocapgraph.formats.vmc import HUMANOID_TABLES, UNITY_BONES
from mocapgraph.retarget.character import Character

# Unity (x right, y up, z forward) from ours (x forward, y left, z up): written out here, not imported
OURS_FROM_UNITY = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def parse(data: bytes) -> dict:
    """One VMC bundle -> {"ok": args, "t": s, "root": (pos, xyzw), "bones": {name: (pos, xyzw)}}."""
    assert OscBundle.dgram_is_bundle(data)
    out: dict = {"bones": {}}
    for m in OscBundle(data):
        a = m.params
        if m.address == "/VMC/Ext/OK":
            out["ok"] = a
        elif m.address == "/VMC/Ext/T":
            out["t"] = a[0]
        elif m.address == "/VMC/Ext/Root/Pos":
            out["root"] = (np.array(a[1:4]), np.array(a[4:8]))
        elif m.address == "/VMC/Ext/Bone/Pos":
            assert a[0] in UNITY_BONES and a[0] not in out["bones"]
            out["bones"][a[0]] = (np.array(a[1:4]), np.array(a[4:8]))
        else:
            raise AssertionError(f"unexpected address {m.address}")
    return out


def unity_world(parsed: dict, ch: Character, bones: dict[str, str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Unity's own forward kinematics over the sent transforms (position = parent position + parent
    rotation * localPosition), bones hung on their nearest sent ancestor: {bone: (pos ours, R ours)}."""
    root_p, root_q = parsed["root"]
    joint_bone = {ch.index(j): b for b, j in bones.items() if b in parsed["bones"]}
    out = {}
    for j in sorted(joint_bone):       # parents before children
        b = joint_bone[j]
        a = int(ch.parents[j])
        while a >= 0 and a not in joint_bone:
            a = int(ch.parents[a])
        if b == "Hips" or a < 0:
            pp, pr = root_p, Rotation.from_quat(root_q).as_matrix()
        else:
            pp, pr = out[joint_bone[a]]
        lp, lq = parsed["bones"][b]
        out[b] = (pp + pr @ lp, pr @ Rotation.from_quat(lq).as_matrix())
    return {b: (OURS_FROM_UNITY @ p, OURS_FROM_UNITY @ r @ OURS_FROM_UNITY.T) for b, (p, r) in out.items()}


def locals_from_bones(world: dict, ch: Character, bones: dict[str, str]) -> np.ndarray:
    """Our local rotations [J, 4] from the sent bones: a bone's change from rest is its world rotation
    (normalized humanoid: identity at rest); a joint that is no bone keeps its parent's change."""
    _, w0 = ch.forward_kinematics(as_matrices=True)
    change = np.empty((ch.n_joints, 3, 3))
    by_joint = {ch.index(j): b for b, j in bones.items() if b in world}
    for j in range(ch.n_joints):
        p = int(ch.parents[j])
        change[j] = world[by_joint[j]][1] if j in by_joint else (change[p] if p >= 0 else np.eye(3))
    w = change @ w0
    rest = Rotation.from_quat(ch.rest_rotations[:, [1, 2, 3, 0]]).as_matrix()
    par = np.where(ch.parents >= 0, ch.parents, 0)
    w_par = np.where((ch.parents >= 0)[:, None, None], w[par], np.eye(3))
    local = np.swapaxes(rest, 1, 2) @ np.swapaxes(w_par, 1, 2) @ w
    return Rotation.from_matrix(local).as_quat()[:, [3, 0, 1, 2]]


def vroid_name(bone: str) -> str:
    side = "L_" if bone.startswith("Left") else "R_" if bone.startswith("Right") else "C_"
    return f"J_Bip_{side}{bone.removeprefix('Left').removeprefix('Right')}"


def write_vrm(path: Path, version: str) -> dict[str, str]:
    """Mixamo's skeleton as a VRM: VRoid-style node names, the humanoid map in the VRM extension
    (1.0: VRMC_vrm, thumbs shifted by one; 0.x: VRM, the avatar facing -Z). Returns Unity bone ->
    Mixamo joint."""
    mix = load_character("mixamo")
    table = {b: j for b, j in HUMANOID_TABLES["mixamo"].items()}
    new = {j: vroid_name(b) for b, j in table.items()}

    renamed = Character("avatar", tuple(new.get(n, "J_Sec_" + n) for n in mix.joint_names), mix.parents,
                        mix.rest_offsets + np.eye(3)[2] * (mix.parents < 0)[:, None] * 0.9, mix.rest_rotations,
                        mix.end_sites, allow_zero_bones=True)
    tmp = path.with_suffix(".glb")
    write_gltf(tmp, renamed)
    doc = pygltflib.GLTF2().load(str(tmp))
    node = {n.name: i for i, n in enumerate(doc.nodes)}
    if version == "1.0":
        def vrm1(b: str) -> str:
            for side in ("Left", "Right"):
                for unity, v1 in (("ThumbProximal", "ThumbMetacarpal"), ("ThumbIntermediate", "ThumbProximal")):
                    if b == side + unity:
                        b = side + v1
            return b[0].lower() + b[1:]
        doc.extensionsUsed = ["VRMC_vrm"]
        doc.extensions = {"VRMC_vrm": {"specVersion": "1.0", "meta": {"name": "test avatar"},
                                       "humanoid": {"humanBones": {vrm1(b): {"node": node[new[j]]}
                                                                   for b, j in table.items()}}}}
    else:
        doc.extensionsUsed = ["VRM"]
        doc.extensions = {"VRM": {"specVersion": "0.0", "humanoid": {"humanBones": [
            {"bone": b[0].lower() + b[1:], "node": node[new[j]], "useDefaultValues": True} for b, j in table.items()]}}}
        root = doc.nodes[doc.scenes[0].nodes[0]]
        root.rotation = [0.0, 1.0, 0.0, 0.0]                     # half a turn about Y: facing -Z
        x, y, z = root.translation
        root.translation = [-x, y, -z]
    doc.save(str(path.with_suffix(".glb")))
    os.replace(path.with_suffix(".glb"), path)
    return table


