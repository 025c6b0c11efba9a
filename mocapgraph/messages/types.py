"""The message types of mocapgraph, with units and frames in every field's doc.

World frame: right-handed, Z up, X forward, metres. Quaternions (w, x, y, z). Missing data is
NaN plus a quality code, never 0,0,0. Names (markers, joints, limbs, bodies) travel once in a
latched message (`MarkerLayout`, `SkeletonModel`, `SkeletonInfo`, `CharacterInfo`,
`PhysicsScene`), never per frame; per-frame arrays follow the order of those names.
"""
from __future__ import annotations

from .schema import Message, array, scalar, strings

from .quality import QUALITY_ESTIMATED, QUALITY_GOOD, QUALITY_MISSING  # noqa: F401  (re-exported)

# Kinect-style tracking states (SkeletonPose.tracking_state).
TRACK_NOT_TRACKED = 0
TRACK_INFERRED = 1
TRACK_TRACKED = 2


class MarkerFrame(Message):
    """One frame of labelled markers from any reader, in the order of the latched MarkerLayout."""

    type_name = "MarkerFrame"
    version = 1
    frame_number: int = scalar("int", "capture frame index as the device numbers it")
    rate_hz: float = scalar("float", "nominal capture rate, Hz")
    positions = array("float64", ("N", 3), "marker positions, m, world frame; NaN where missing")
    valid = array("bool", ("N",), "True where the marker was seen this frame")
    residual = array("float32", ("N",), "per-marker fit residual from the device, m; NaN if unknown")


class MarkerLayout(Message):
    """Latched: which marker is which and which limb it rides."""

    type_name = "MarkerLayout"
    version = 1
    latched_by_default = True
    name: str = scalar("str", "layout name, e.g. kiip_full_body")
    labels = strings("marker labels in MarkerFrame order")
    limb_names = strings("limb names")
    marker_limb = array("int32", ("N",), "limb index of each marker, -1 if it rides none")
    units_note: str = scalar("str", "what the reader converted (units, axes) to reach the world frame")
    unplaced = strings("labels the source had that the layout could not place")
    source: str = scalar("str", "where the frames come from (file, device, synthetic)")


class SkeletonModel(Message):
    """Latched: a calibrated actor skeleton (marker-to-joint offsets, base pose, limb lengths)."""

    type_name = "SkeletonModel"
    version = 2
    latched_by_default = True
    layout_name: str = scalar("str", "marker layout the model was calibrated with")
    fingerprint: str = scalar("str", "hash of the marker labels, to refuse a model from another layout")
    marker_labels = strings("marker labels, layout order")
    limb_names = strings("limb names")
    joint_names = strings("joint names")
    marker_limb = array("int32", ("M",), "limb index of each marker")
    limb_parent = array("int32", ("L",), "parent limb index, -1 for the root")
    joint_limbs = array("int32", ("J", 2), "proximal and distal limb of each joint")
    joint_parent = array("int32", ("J",), "parent joint index, -1 if none")
    joint_hinge = array("bool", ("J",), "True for hinge joints")
    base_markers = array("float64", ("M", 3), "marker positions in the base pose, m, world")
    joint_offsets = array(
        "float64", ("J", 2, 3),
        "joint offset from each of its two limbs' base-pose marker centroid, m, base-pose world frame",
    )
    base_joints = array("float64", ("J", 3), "joint centres in the base pose, m, world")
    bone_lengths = array("float64", ("J",), "distance from each joint to its parent joint, m; NaN for roots")
    hinge_axes = array("float64", ("J", 3), "hinge axis in the base-pose world frame (unit); NaN for ball joints")
    joint_residual_rms = array("float64", ("J",), "calibration residual RMS per joint, m")
    joint_rom = array("float64", ("J",), "range of motion covered during calibration, rad")
    # v2 (issue 27): S = J, or 0 from a model without standard errors; covariances, hinge axis errors
    # and the joints found from a degenerate cluster's markers as points travel in extra_json
    joint_centre_se = array("float64", ("S",), "standard error (RMS 3-D) of each calibrated centre, m; "
                            "NaN where unknown")
    extra_json: str = scalar("str", "further model data as JSON (filters, notes); may be empty")


class ActorPose(Message):
    """Solved actor skeleton for one frame, in the order of the latched SkeletonModel."""

    type_name = "ActorPose"
    version = 2
    actor: str = scalar("str", "actor name")
    frame_number: int = scalar("int", "capture frame index of the markers it was solved from")
    joint_positions = array("float64", ("J", 3), "joint centres, m, world; NaN where missing")
    joint_quality = array("int8", ("J",), "0 missing, 1 estimated, 2 good")
    limb_orientations = array("float64", ("L", 4), "limb rotation from its base pose, quaternion wxyz, world")
    limb_quality = array("int8", ("L",), "0 missing, 1 estimated, 2 good")
    limb_visible_markers = array("int16", ("L",), "markers of each limb seen this frame")
    # v2 (issue 27): U = J, or 0 when the model has no standard errors
    joint_uncertainty = array("float64", ("U",), "RMS 3-D uncertainty of each joint, m (calibrated centre's "
                              "standard error with this frame's marker noise); NaN where missing or unknown")


class SkeletonInfo(Message):
    """Latched: joint definitions of a skeleton stream (Kinect, BVH playback)."""

    type_name = "SkeletonInfo"
    version = 1
    latched_by_default = True
    source: str = scalar("str", "device or file kind, e.g. kinect_v2, bvh")
    joint_names = strings("joint names, SkeletonPose order")
    joint_parent = array("int32", ("J",), "parent joint index, -1 for the root")
    rest_offsets = array("float64", ("J", 3), "joint offset from its parent in the rest pose, m")
    units_note: str = scalar("str", "what the source converted to reach the world frame")


class SkeletonPose(Message):
    """One frame of a generic joint stream (Kinect, BVH playback)."""

    type_name = "SkeletonPose"
    version = 1
    source_id: str = scalar("str", "which performer / body index")
    frame_number: int = scalar("int", "frame index of the source")
    joint_positions = array("float64", ("J", 3), "joint positions, m, world; NaN if not tracked")
    joint_orientations = array("float64", ("J", 4), "joint world orientations, wxyz; NaN if unknown")
    tracking_state = array("int8", ("J",), "0 not tracked, 1 inferred, 2 tracked")


class ImageLandmarks(Message):
    """One camera frame's 2D body landmarks (the pose estimator's), for triangulating several cameras."""

    type_name = "ImageLandmarks"
    version = 1
    camera: str = scalar("str", "camera name, as the calibration names it")
    frame_number: int = scalar("int", "frame index of the camera (or of the file streamed as if live)")
    width: int = scalar("int", "image width, px")
    height: int = scalar("int", "image height, px")
    rate_hz: float = scalar("float", "the camera's frame rate as captured, Hz (a file streamed as if live: its "
                            "rate x rate_scale / every)")
    points = array("float64", ("N", 2), "landmark image positions, px (x right, y down, distorted); NaN if not seen")
    confidence = array("float32", ("N",), "estimator confidence of each landmark, 0..1 (0 where not seen)")


class RigidBodyLayout(Message):
    """Latched: the rigid bodies of a tracking system (names, device ids, parents), RigidBodyFrame order."""

    type_name = "RigidBodyLayout"
    version = 1
    latched_by_default = True
    names = strings("rigid body names, RigidBodyFrame order")
    ids = array("int32", ("R",), "the device's id of each body (NatNet streaming id)")
    parent = array("int32", ("R",), "index of the parent body, -1 for none")
    units_note: str = scalar("str", "what the reader converted to reach the world frame")
    source: str = scalar("str", "where the bodies come from (device, server)")


class RigidBodyFrame(Message):
    """One frame of tracked rigid bodies, in the order of the latched RigidBodyLayout."""

    type_name = "RigidBodyFrame"
    version = 1
    frame_number: int = scalar("int", "capture frame index as the device numbers it")
    positions = array("float64", ("R", 3), "body origin, m, world frame; NaN where not tracked")
    orientations = array("float64", ("R", 4), "body orientation, wxyz, world frame; NaN where not tracked")
    error = array("float32", ("R",), "mean marker error of the fit reported by the device, m; NaN where not tracked")
    quality = array("int8", ("R",), "0 missing (not tracked or not valid), 2 good")


class CharacterInfo(Message):
    """Latched: a user character's skeleton (names, parents, rest offsets)."""

    type_name = "CharacterInfo"
    version = 2
    latched_by_default = True
    character: str = scalar("str", "character name")
    joint_names = strings("joint names, CharacterPose order")
    joint_parent = array("int32", ("J",), "parent joint index, -1 for the root")
    rest_offsets = array("float64", ("J", 3), "joint offset from its parent in the rest pose, m, "
                         "parent frame (the root's: its rest position, world)")
    rest_rotations = array("float64", ("J", 4), "rest orientation relative to the parent, wxyz "
                           "(world = W[parent] * rest * local; identity for BVH rigs)")


class CharacterPose(Message):
    """A retargeted character pose."""

    type_name = "CharacterPose"
    version = 2
    character: str = scalar("str", "character name")
    frame_number: int = scalar("int", "source frame index")
    root_position = array("float64", (3,), "root joint position, m, world")
    local_rotations = array("float64", ("J", 4), "joint rotations relative to the rest orientation in the "
                            "parent's frame, wxyz; never NaN (a joint whose source is missing keeps its "
                            "last rotation)")
    joint_positions = array("float64", ("J", 3), "joint positions, m, world, computed from local_rotations")
    joint_quality = array("int8", ("J",), "0 missing (never seen: rest pose), 1 estimated (held or "
                          "depending on a held source), 2 good")


class PhysicsScene(Message):
    """Latched: the bodies of a simulated stage (names, shapes, sizes)."""

    type_name = "PhysicsScene"
    version = 1
    latched_by_default = True
    body_names = strings("body names, PhysicsState order")
    shapes = strings("shape per body: capsule, box, sphere, cylinder, mesh")
    sizes = array("float64", ("B", 3), "shape sizes, m (MuJoCo size convention)")


class PhysicsState(Message):
    """Simulated bodies for one step."""

    type_name = "PhysicsState"
    version = 1
    sim_time_s: float = scalar("float", "simulation time, s")
    positions = array("float64", ("B", 3), "body positions, m, world")
    orientations = array("float64", ("B", 4), "body orientations, wxyz")
    tracking_error = array("float64", ("B",), "distance from the tracked target, m; NaN if untracked")


class Diagnostics(Message):
    """A node's health: per incoming edge rate, latency, gaps and rejects; per output counts."""

    type_name = "Diagnostics"
    version = 3
    node: str = scalar("str", "node name")
    pid: int = scalar("int", "process id")
    uptime_s: float = scalar("float", "seconds since the node started")
    cpu_s: float = scalar("float", "CPU seconds used by the process")
    edge_topics = strings("topic of each incoming edge")
    edge_senders = strings("sending node of each incoming edge")
    edge_rate_hz = array("float64", ("E",), "rate from sender publish stamps over the last window, Hz")
    edge_latency_ms = array("float64", ("E",), "median publish-to-receive latency over the window, ms")
    edge_latency_max_ms = array("float64", ("E",), "maximum latency over the window, ms")
    edge_received = array("int64", ("E",), "messages received since start")
    edge_gaps = array("int64", ("E",), "messages lost according to sequence numbers since start")
    edge_rejected = array("int64", ("E",), "malformed frames rejected on this input since start")
    edge_anomalies = array("int64", ("E",), "sequence anomalies (restarts, jumps beyond belief) resynchronised since start")
    output_topics = strings("published topics")
    output_sent = array("int64", ("O",), "messages published per output since start")
    clock_names = strings("clocks this node maps onto its own: device streams (messages.clock_sync), other machines")
    clock_offset_ms = array("float64", ("C",), "our clock minus that clock at its latest sample, ms")
    clock_drift_ppm = array("float64", ("C",), "how much faster that clock runs than ours, ppm")
    clock_jitter_ms = array("float64", ("C",), "standard deviation of the delay above the fastest samples, ms")
    clock_resets = array("int64", ("C",), "times that clock restarted or jumped and was re-seeded since start")


class NodeCommand(Message):
    """A command to a node's state machine (e.g. calibration: find_base_pose, capture_gym)."""

    type_name = "NodeCommand"
    version = 1
    target: str = scalar("str", "node name the command is for ('' for every listener)")
    command: str = scalar("str", "command name")
    args_json: str = scalar("str", "arguments as a JSON object", "{}")


class NodeStatus(Message):
    """A node's state-machine state, reported on change and periodically."""

    type_name = "NodeStatus"
    version = 1
    node: str = scalar("str", "node name")
    state: str = scalar("str", "current state")
    detail: str = scalar("str", "human-readable detail or error")
    progress: float = scalar("float", "0..1 progress of the current state, NaN if unknown")
    data_json: str = scalar("str", "state data as JSON (e.g. per-joint quality)", "{}")
