"""VMC protocol bundles from character poses: Unity humanoid bones, Unity's axes, one OSC bundle per pose.

The VMC protocol (https://protocol.vmc.info, OSC over UDP, receivers on port 39539: EVMC4U in
Unity, VMC4UE/VRM4U in Unreal, VMC4B in Blender, VSeeFace, VMagicMirror) moves a humanoid avatar
with, per frame::

    /VMC/Ext/OK        i i i i          loaded 1, calibration state 3 (calibrated), mode 0 (normal),
                                        tracking 1 (every sent bone good) or 0
    /VMC/Ext/T         f                sender time, s (capture time since the first pose sent)
    /VMC/Ext/Root/Pos  s f f f f f f f  "root", position x y z, rotation x y z w (Unity axes)
    /VMC/Ext/Bone/Pos  s f f f f f f f  Unity HumanBodyBones name, localPosition, localRotation

Frames. Ours: Z up, X forward, Y left, right-handed (``formats/axes.py``). Unity: Y up, Z forward,
X right, left-handed; ``unity = M @ ours`` with ``M`` below (a reflection: a quaternion's vector
part becomes ``-M v``). A VMC avatar is a normalized humanoid: every bone's rotation is identity in
the rest pose (T-pose), so a bone's rotation is the change from the character's rest orientation,
in the world-aligned frame of its humanoid parent: with ``D[j] = W[j] W0[j]^-1`` (world
orientation now, times its inverse at rest), ``local[b] = D[a]^-1 D[b]`` for bone ``b`` under
humanoid bone ``a``; the rest pose sends identities. localPosition is ``D[a]^-1 (P[b] - P[a])``
(the rest offset unless joints that are no humanoid bone bend in between), so ``P[b] = P[a] +
D[a] localPosition`` reproduces every sent joint. The root message carries the translation:
position = the hips' displacement from their rest place, rotation identity; the Hips bone's
localPosition is their rest place. Bones a character lacks are left out.

The bundle is laid out once per character by python-osc (a template) and filled per frame with
numpy (big-endian float32), as :mod:`mocapgraph.formats.osc_frames` does.
"""
from __future__ import annotations

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder

from ..kinematics.quaternion import matrix_to_quat
from ..retarget.character import Character

#: ours -> Unity: unity x (right) = -our y (left), unity y (up) = our z, unity z (forward) = our x
M_TO_UNITY = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])

#: Unity's HumanBodyBones names a VMC receiver knows (fingers: Proximal, Intermediate, Distal)
UNITY_BONES: tuple[str, ...] = (
    "Hips", "LeftUpperLeg", "RightUpperLeg", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot",
    "Spine", "Chest", "UpperChest", "Neck", "Head", "LeftShoulder", "RightShoulder", "LeftUpperArm",
    "RightUpperArm", "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand", "LeftToes", "RightToes",
    "LeftEye", "RightEye", "Jaw",
    *(f"{side}{finger}{part}" for side in ("Left", "Right") for finger in ("Thumb", "Index", "Middle", "Ring", "Little")
      for part in ("Proximal", "Intermediate", "Distal")),
)


def _sided(pairs: dict[str, str]) -> dict[str, str]:
    """Expand "{S}" / "{s}" in a table to Left/Right (Unity bone) and the joint's own side spelling."""
    out = {}
    for bone, joint in pairs.items():
        for side, short in (("Left", "L"), ("Right", "R")):
            out[bone.replace("{S}", side)] = joint.replace("{S}", side).replace("{s}", short)
    return out


_MIXAMO_FINGERS = {f"{{S}}{u}{part}": f"{{S}}Hand{m}{i}"
                   for u, m in (("Thumb", "Thumb"), ("Index", "Index"), ("Middle", "Middle"), ("Ring", "Ring"),
                                ("Little", "Pinky"))
                   for i, part in ((1, "Proximal"), (2, "Intermediate"), (3, "Distal"))}

#: Unity bone -> joint, per shipped character (graph_configs/characters); the hips first
HUMANOID_TABLES: dict[str, dict[str, str]] = {
    "mixamo": {"Hips": "Hips", "Spine": "Spine", "Chest": "Spine1", "UpperChest": "Spine2", "Neck": "Neck",
               "Head": "Head", **_sided({"{S}Eye": "{S}Eye", "{S}Shoulder": "{S}Shoulder", "{S}UpperArm": "{S}Arm",
                                         "{S}LowerArm": "{S}ForeArm", "{S}Hand": "{S}Hand",
                                         "{S}UpperLeg": "{S}UpLeg", "{S}LowerLeg": "{S}Leg", "{S}Foot": "{S}Foot",
                                         "{S}Toes": "{S}ToeBase", **_MIXAMO_FINGERS})},
    # CMU: LHipJoint/RHipJoint, lhand/rhand and the finger stubs are no humanoid bones
    "cmu": {"Hips": "Hips", "Spine": "lowerback", "Chest": "Chest", "UpperChest": "Chest2", "Neck": "Neck",
            "Head": "Head", **_sided({"{S}Shoulder": "{S}Collar", "{S}UpperArm": "{S}Shoulder",
                                      "{S}LowerArm": "{S}Elbow", "{S}Hand": "{S}Wrist", "{S}UpperLeg": "{S}Hip",
                                      "{S}LowerLeg": "{S}Knee", "{S}Foot": "{S}Ankle", "{S}Toes": "{S}Toe"})},
    # standard_20 (Kinect v1 names): no neck joint (ShoulderCenter -> Head is the neck), hands are leaves
    "standard_20": {"Hips": "HipCenter", "Spine": "Spine", "Chest": "ShoulderCenter", "Head": "Head",
                    **{f"{s}{u}": f"{k}{s}" for s in ("Left", "Right")
                       for u, k in (("UpperArm", "Shoulder"), ("LowerArm", "Elbow"), ("Hand", "Wrist"),
                                    ("UpperLeg", "Hip"), ("LowerLeg", "Knee"), ("Foot", "Ankle"), ("Toes", "Foot"))}},
    # joints already named as Unity's bones (a VRM or Unity export)
    "unity": {b: b for b in UNITY_BONES},
}


class VMCError(ValueError):
    """A humanoid bone table that does not fit a character (one line)."""


def humanoid_bones(ch: Character, table: dict[str, str] | str | None = None) -> dict[str, str]:
    """Unity bone -> joint of ``ch``: the table given (a dict, or a name of HUMANOID_TABLES), else the
    shipped table naming the most of the character's joints. Bones the character lacks are left out;
    a given table naming a joint the character lacks is a VMCError. The hips must be there."""
    names = set(ch.joint_names)
    if isinstance(table, dict) and table:
        unknown = sorted(b for b in table if b not in UNITY_BONES)
        if unknown:
            raise VMCError(f"bones: {', '.join(unknown[:3])} are not Unity humanoid bones")
        missing = sorted(j for j in table.values() if j not in names)
        if missing:
            raise VMCError(f"bones: character {ch.name!r} has no joint {', '.join(map(repr, missing[:3]))}")
        chosen = dict(table)
    else:
        if isinstance(table, str) and table:
            if table not in HUMANOID_TABLES:
                raise VMCError(f"bones: no table {table!r} (known: {', '.join(HUMANOID_TABLES)})")
            candidates = {table: HUMANOID_TABLES[table]}
        else:
            candidates = HUMANOID_TABLES
        score = {k: sum(j in names for j in t.values()) for k, t in candidates.items()}
        best = max(score, key=lambda k: score[k])
        chosen = {b: j for b, j in candidates[best].items() if j in names}
    if "Hips" not in chosen:
        raise VMCError(f"character {ch.name!r}: no joint maps to the Hips (give a `bones` table: Unity bone -> joint)")
    if len(set(chosen.values())) != len(chosen):
        raise VMCError("bones: one joint is given to two Unity bones")
    return chosen


def to_unity_quat_xyzw(q_wxyz: np.ndarray) -> np.ndarray:
    """Our rotation quaternions (w, x, y, z) as Unity's (x, y, z, w): vector part -M v."""
    q = np.asarray(q_wxyz, dtype=np.float64)
    v = -(q[..., 1:] @ M_TO_UNITY.T)
    return np.concatenate([v, q[..., :1]], axis=-1)


class VMCBundle:
    """The VMC bundle template of one character: ``encode(local_rotations, root_position, quality, t_s)``."""

    def __init__(self, ch: Character, bones: dict[str, str] | str | None = None) -> None:
        self.character = ch
        self.bones = humanoid_bones(ch, bones)
        # the Hips first, then by joint order (parents before children)
        order = ["Hips"] + sorted((b for b in self.bones if b != "Hips"), key=lambda b: ch.index(self.bones[b]))
        self.bone_names = order
        self.joint_of = np.array([ch.index(self.bones[b]) for b in order])
        # humanoid parent of each bone: nearest ancestor joint that is a sent bone (-1: none)
        bone_of_joint = {int(j): i for i, j in enumerate(self.joint_of)}
        par = []
        for j in self.joint_of:
            a = int(ch.parents[j])
            while a >= 0 and a not in bone_of_joint:
                a = int(ch.parents[a])
            par.append(bone_of_joint.get(a, -1))
        par[0] = -1   # the Hips hang from the root message
        self.bone_parent = np.array(par, dtype=np.int64)
        p0, w0 = ch.forward_kinematics(as_matrices=True)
        self._w0_t = np.swapaxes(w0, -1, -2)  # [J, 3, 3] rest orientations, inverted
        self.hips_rest = p0[ch.index(self.bones["Hips"])]
        self._build_template()

    def _build_template(self) -> None:
        parts = []
        b = OscMessageBuilder("/VMC/Ext/OK")
        for v in (1, 3, 0, 1):
            b.add_arg(v, "i")
        parts.append((b.build(), 4))
        b = OscMessageBuilder("/VMC/Ext/T")
        b.add_arg(0.0, "f")
        parts.append((b.build(), 1))
        for addr, name in [("/VMC/Ext/Root/Pos", "root")] + [("/VMC/Ext/Bone/Pos", n) for n in self.bone_names]:
            b = OscMessageBuilder(addr)
            b.add_arg(name, "s")
            for _ in range(7):
                b.add_arg(0.0, "f")
            parts.append((b.build(), 7))
        bb = OscBundleBuilder(IMMEDIATELY)
        for p, _ in parts:
            bb.add_content(p)
        whole = bb.build().dgram
        self.template = np.frombuffer(whole, np.uint8).copy()
        pos, starts, ends, slots = 16, [], [], []
        for p, n_args in parts:
            starts.append(pos)
            pos += 4 + p.size
            ends.append(pos)
            slots.append(pos - 4 * n_args)
        assert pos == len(whole)
        self._tracking = slots[0] + 12 + np.arange(4)
        self._time = slots[1] + np.arange(4)
        # root and bones: 7 float32 each, in message order
        self._floats = (np.asarray(slots[2:])[:, None] + np.arange(28)).ravel()
        self._starts = np.asarray(starts)
        self._lengths = np.asarray(ends) - self._starts

    def unity_pose(self, local_rotations: np.ndarray, root_position: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(root position [3], bone local positions [B, 3], bone local rotations [B, 4] xyzw), Unity axes."""
        ch = self.character
        p, w = ch.forward_kinematics(local_rotations, root_position, as_matrices=True)
        d = w @ self._w0_t                                   # [J, 3, 3] change from rest, world frame
        jb = self.joint_of
        has_par = self.bone_parent >= 0
        pj = jb[np.where(has_par, self.bone_parent, 0)]
        d_par = np.where(has_par[:, None, None], d[pj], np.eye(3))
        p_par = np.where(has_par[:, None], p[pj], 0.0)
        local_r = np.swapaxes(d_par, -1, -2) @ d[jb]
        local_p = (np.swapaxes(d_par, -1, -2) @ (p[jb] - p_par)[..., None])[..., 0]
        root = p[jb[0]] - self.hips_rest    # the Hips (first): the root carries their displacement
        local_p[0] = self.hips_rest
        q = matrix_to_quat(local_r)
        return root @ M_TO_UNITY.T, local_p @ M_TO_UNITY.T, to_unity_quat_xyzw(q)

    def encode(self, local_rotations: np.ndarray, root_position: np.ndarray, quality: np.ndarray,
               t_s: float) -> bytes:
        """One bundle. Bones with a non-finite value are left out; tracking says 1 when every sent
        bone is good (quality 2), else 0."""
        root, lp, lq = self.unity_pose(local_rotations, root_position)
        values = np.concatenate([np.r_[root, 0.0, 0.0, 0.0, 1.0][None], np.concatenate([lp, lq], axis=1)])
        ok = np.isfinite(values).all(axis=1)
        buf = self.template.copy()
        buf[self._floats] = np.ascontiguousarray(np.where(ok[:, None], values, 0.0), ">f4").view(np.uint8).ravel()
        good = bool((np.asarray(quality)[self.joint_of][ok[1:]] >= 2).all())
        buf[self._tracking] = np.frombuffer(np.array(int(good), ">i4").tobytes(), np.uint8)
        buf[self._time] = np.frombuffer(np.array(t_s, ">f4").tobytes(), np.uint8)
        if ok.all():
            return buf.tobytes()
        keep = np.r_[True, True, ok]
        starts, lengths = self._starts[keep], self._lengths[keep]
        idx = np.repeat(starts - np.cumsum(np.r_[0, lengths[:-1]]), lengths) + np.arange(lengths.sum())
        return buf[:16].tobytes() + buf[idx].tobytes()
