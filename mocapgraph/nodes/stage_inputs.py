"""The stage's input set: the topics a live view of the graph draws (the visualizer, the Foxglove bridge).

One table, so a view that learns to draw a new stream learns it for every view. Each entry is
an optional subscription: a topic that nothing publishes is simply not shown. The views differ
only in how many messages a socket may hold (``queue``), which `stage_inputs` takes.
"""
from __future__ import annotations

from ..bus import Input
from ..messages import (ActorPose, CharacterInfo, CharacterPose, Diagnostics, MarkerFrame, MarkerLayout, Message,
                        NodeStatus, PhysicsScene, PhysicsState, SkeletonInfo, SkeletonModel, SkeletonPose)

#: port name -> (topic, message type, what the view draws of it, latched)
STAGE_TOPICS: dict[str, tuple[str, type[Message], str, bool]] = {
    "markers": ("markers", MarkerFrame, "labelled markers, drawn green (seen) or red (not seen)", False),
    "marker_layout": ("marker_layout", MarkerLayout, "marker labels (names of missing markers)", True),
    "actor_pose": ("actor_pose", ActorPose, "solved actors: joints and bones coloured by quality", False),
    "skeleton_model": ("skeleton_model", SkeletonModel, "calibrated models: bones and per-joint quality", True),
    "skeleton_pose": ("skeleton_pose", SkeletonPose, "generic joint streams (Kinect, BVH)", False),
    "skeleton_info": ("skeleton_info", SkeletonInfo, "joint names and parents of skeleton streams", True),
    "character_pose": ("character_pose", CharacterPose, "retargeted characters", False),
    "character_info": ("character_info", CharacterInfo, "character skeletons (parents for bones)", True),
    "physics_state": ("physics_state", PhysicsState, "simulated bodies and stage objects", False),
    "physics_scene": ("physics_scene", PhysicsScene, "body shapes and sizes", True),
    "node_diagnostics": ("diagnostics", Diagnostics, "every node's edge rates, latency and drops", False),
    "calibration_status": ("calibration_status", NodeStatus, "calibration state machine", False),
    "player_status": ("player_status", NodeStatus, "bag player state (position, duration)", False),
}


def stage_inputs(queue: int) -> type:
    """A base class declaring every stage topic as an optional input holding ``queue`` messages.

    A view subclasses it beside `Node` (``class Visualizer(stage_inputs(64), Node)``): the
    declarations are class attributes like any others, found by ``declared_interface``."""
    ports = {name: Input.optional(topic, msg_type, doc, queue=queue, latched=latched)
             for name, (topic, msg_type, doc, latched) in STAGE_TOPICS.items()}
    return type(f"StageInputs{queue}", (), {"__doc__": f"The stage's inputs, {queue} messages a socket.", **ports})
