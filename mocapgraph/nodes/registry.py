"""Node types by registry name. Graph files name a node type here, as mocapgraph.module:Class, or as a file.py:Class.

Entries are import paths, so listing the registry imports nothing heavy; a node's module is
imported only when a graph uses it or `mocapgraph node info` asks for it.
"""
from __future__ import annotations

NODE_TYPES: dict[str, str] = {
    "marker_test_pattern": "mocapgraph.testing.marker_pattern:MarkerTestPattern",
    "topic_logger": "mocapgraph.nodes.topic_logger:TopicLogger",
    # inputs: marker readers (markers + marker_layout) and skeleton sources (skeleton_pose + skeleton_info)
    "synthetic_actor": "mocapgraph.nodes.synthetic_actor:SyntheticActorNode",
    "c3d_reader": "mocapgraph.nodes.c3d_reader:C3DReader",
    "trc_reader": "mocapgraph.nodes.trc_reader:TRCReader",
    "serial_reader": "mocapgraph.nodes.serial_reader:SerialReader",
    "udp_reader": "mocapgraph.nodes.udp_reader:UDPReader",
    "lsl_reader": "mocapgraph.nodes.lsl_reader:LSLReader",
    "qtm_reader": "mocapgraph.nodes.qtm_reader:QTMReader",
    "natnet_reader": "mocapgraph.nodes.natnet_reader:NatNetReader",
    "kinect_reader": "mocapgraph.nodes.kinect_reader:KinectReader",
    "video_pose_reader": "mocapgraph.nodes.video_pose_reader:VideoPoseReader",
    "multiview_pose": "mocapgraph.nodes.video_pose_reader:MultiviewPose",
    "video_camera_reader": "mocapgraph.nodes.video_camera_reader:VideoCameraReader",
    "multiview_live": "mocapgraph.nodes.multiview_live:MultiviewLive",
    "bvh_player": "mocapgraph.nodes.bvh_player:BVHPlayer",
    "c3d_segment_reader": "mocapgraph.nodes.c3d_segment_reader:C3DSegmentReader",
    # actor: calibration (latched SkeletonModel) and the per-frame solver (ActorPose)
    "calibration": "mocapgraph.nodes.calibration:CalibrationNode",
    "frame_solver": "mocapgraph.nodes.frame_solver:FrameSolverNode",
    # characters: retargeting (CharacterPose), a ground-truth character source, physics
    "retargeter": "mocapgraph.nodes.retargeter:RetargeterNode",
    "synthetic_character": "mocapgraph.nodes.synthetic_character:SyntheticCharacterNode",
    "physics_tracker": "mocapgraph.nodes.physics_tracker:PhysicsTrackerNode",
    "bag_recorder": "mocapgraph.nodes.bag_recorder:BagRecorder",
    "bag_player": "mocapgraph.nodes.bag_player:BagPlayer",
    "visualizer": "mocapgraph.nodes.visualizer:Visualizer",
    # outputs to other tools: Foxglove, LabStreamingLayer, OSC, VMC
    "foxglove_bridge": "mocapgraph.nodes.foxglove_bridge:FoxgloveBridge",
    "lsl_outlet": "mocapgraph.nodes.lsl_outlet:LSLOutlet",
    "osc_outlet": "mocapgraph.nodes.osc_outlet:OSCOutlet",
    "vmc_outlet": "mocapgraph.nodes.vmc_outlet:VMCOutlet",
}


def resolve(type_name: str) -> str:
    """``module:Class`` for a registry name or an import path; KeyError when unknown."""
    if ":" in type_name:
        return type_name
    return NODE_TYPES[type_name]
