"""Automatic mappings onto a VRM/humanoid avatar: its humanoid bone map stands in for a mapping file.

The automatic mapping (:func:`mocapgraph.retarget.mapping.derive_mapping`) pairs joints by their
anatomical role, which it knows from the joint names of the common rigs. A VRM avatar's nodes are
named by whoever built it (``J_Bip_L_UpperLeg``), but its humanoid map says which node is which
Unity bone. So the mapping is derived on a copy of the character whose humanoid joints carry the
Mixamo names of those bones (the other joints a name no rig uses), and the result is renamed
back: the same geometry, the avatar's own joint names.
"""
from __future__ import annotations

from dataclasses import replace

from ..retarget.character import Character
from ..retarget.mapping import Mapping, derive_mapping
from ..retarget.source import SourceSkeleton
from .vmc import HUMANOID_TABLES

_OTHER = "~"   # prefix of the copy's non-humanoid joints (no rig's role table has it)


def with_rig_names(ch: Character, humanoid: dict[str, str]) -> tuple[Character, dict[str, str]]:
    """(a copy of ``ch`` with its humanoid joints named as Mixamo's, copy name -> own name)."""
    to_mixamo = dict(HUMANOID_TABLES["mixamo"])
    if "UpperChest" not in humanoid:
        to_mixamo["Chest"] = "Spine2"       # the chest role sits on Mixamo's Spine2
    rename = {joint: to_mixamo[bone] for bone, joint in humanoid.items() if bone in to_mixamo}
    names = tuple(rename.get(n, _OTHER + n) for n in ch.joint_names)
    copy = Character(ch.name, names, ch.parents, ch.rest_offsets, ch.rest_rotations, ch.end_sites,
                     allow_zero_bones=True)
    return copy, dict(zip(names, ch.joint_names))


def humanoid_mapping(ch: Character, humanoid: dict[str, str], source: SourceSkeleton) -> Mapping:
    """The automatic mapping of ``source`` onto ``ch``, joints paired through the humanoid map."""
    copy, back = with_rig_names(ch, humanoid)
    m = derive_mapping(copy, source)
    joints = tuple(replace(e, joint=back[e.joint], roll_of=back.get(e.roll_of, e.roll_of) if e.roll_of else None)
                   for e in m.joints)
    legs = {side: tuple(back.get(n, n) if n else n for n in names) for side, names in m.legs.items()}
    return replace(m, character=ch.name, joints=joints, legs=legs)
