"""Retargeting set up from files: character and mapping files plus a source, as the node and the batch command build it.

The source is described by what the stream latches (SkeletonInfo, or an actor's SkeletonModel);
a Kinect stream (Kinect v1/v2 joint names, no orientations) takes the canonical T-pose as its rest
pose. An empty mapping derives one automatically from the two rest poses.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..retarget.character import Character
from ..retarget.joint_roles import rig_of
from ..retarget.retargeter import RetargetOptions, Retargeter
from ..retarget.mapping import Mapping, MappingError, derive_mapping
from ..retarget.source import SourceSkeleton, kinect_source, optical_source, skeleton_source
from .character_file import load_character
from .mapping_file import load_mapping, write_mapping


@dataclass
class RetargetSetup:
    character: Character
    mapping: Mapping
    source: SourceSkeleton
    retargeter: Retargeter
    derived: bool               # True: the mapping was derived automatically


def source_from_skeleton_info(names, parents, rest_offsets, *, has_orientations: bool) -> SourceSkeleton:
    """A skeleton stream's source: Kinect names without orientations use the Kinect T-pose."""
    rig = rig_of(names)
    if not has_orientations and rig in ("kinect_v1", "kinect_v2"):
        # a Kinect has no rest pose: the canonical T-pose's directions, the stream's bone lengths
        # (its SkeletonInfo gives observed ones)
        lengths = np.linalg.norm(np.asarray(rest_offsets, dtype=np.float64), axis=1)
        lengths[np.asarray(parents) < 0] = np.nan
        return kinect_source(list(names), np.asarray(parents), kind_hint=rig, bone_lengths=lengths)
    hint = "bvh" if has_orientations else "skeleton"
    return skeleton_source(list(names), np.asarray(parents), np.asarray(rest_offsets),
                           has_orientations=has_orientations, kind_hint=hint)


def source_from_model(joint_names, joint_parent, joint_limbs, limb_names, base_joints, layout: str = "") -> SourceSkeleton:
    """An optical actor's source (its SkeletonModel)."""
    return optical_source(list(joint_names), np.asarray(joint_parent), np.asarray(joint_limbs), list(limb_names),
                          np.asarray(base_joints), layout)


def build(character: str | Path | Character, mapping: str | Path | Mapping | None, source: SourceSkeleton,
          options: RetargetOptions | None = None, *, height_m: float | None = None,
          write_derived: str | Path | None = None) -> RetargetSetup:
    """Character (name, file or object), mapping (name, file, object or None: automatic), source."""
    ch = character if isinstance(character, Character) else load_character(character, height_m=height_m or None)
    derived = False
    if isinstance(mapping, Mapping):
        m = mapping
    elif mapping:
        m = load_mapping(mapping)
    else:
        m = _derive(ch, character, source)
        derived = True
        if write_derived:
            write_mapping(m, write_derived, comment=f"derived automatically: {source.kinect_like or source.kind} onto "
                                                    f"{ch.name}; edit freely")
    rt = Retargeter(ch, m, source, options)
    return RetargetSetup(ch, m, source, rt, derived)


def _derive(ch: Character, character: str | Path | Character, source: SourceSkeleton) -> Mapping:
    """The automatic mapping; through the humanoid bone map of a VRM character file."""
    if not isinstance(character, Character) and Path(character).suffix.lower() in (".vrm", ".glb", ".gltf"):
        from .gltf_character import load_gltf_character
        from .humanoid_rig import humanoid_mapping
        humanoid = load_gltf_character(character).humanoid
        if humanoid:
            return humanoid_mapping(ch, humanoid, source)
    return derive_mapping(ch, source)


__all__ = ["RetargetSetup", "build", "source_from_model", "source_from_skeleton_info", "MappingError"]
