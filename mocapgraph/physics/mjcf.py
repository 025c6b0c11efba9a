"""The MuJoCo model (MJCF) of a physics world: floor, characters, their foot pins, the stage, held-object welds."""
from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np

from .body import CharacterBody, add_character, add_pins, fmt, to_xml, world_root
from .params import TrackerParams
from .stage import Stage, add_stage


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


def build_model(bodies: list[CharacterBody], stage: Stage, params: TrackerParams) -> tuple[str, mujoco.MjModel]:
    """The world's MJCF and the MuJoCo model compiled from it."""
    xml = build_xml(bodies, stage, params)
    return xml, mujoco.MjModel.from_xml_string(xml)
