"""Small real nodes that feed the viewer in its tests, benchmark and example graphs.

- `StagePerformer`: a procedural performer walking a circle, published as any of markers,
  actor pose + skeleton model, skeleton pose + info, character pose + info, physics state + scene
  (param ``publish``), with deterministic missing and unseen markers.
- `CommandEcho`: a tiny state machine answering `NodeCommand` with `NodeStatus`, in the role of a
  calibration node or of a bag player (param ``role``).
- `ForcePlateSource`: publishes `ForcePlateSample`, a message type the page does not know.

They are fixtures of the viewer, not stand-ins for the real calibration node or bag player.
"""
from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from ..bus import Input, Interface, Node, Output, Param
from ..messages.commands import CALIBRATION_COMMANDS, PLAYER_COMMANDS, parse_command
from ..messages import (QUALITY_ESTIMATED, QUALITY_GOOD, QUALITY_MISSING, TRACK_INFERRED, TRACK_TRACKED,
                         ActorPose, CharacterInfo, CharacterPose, MarkerFrame, MarkerLayout, Message, NodeCommand,
                         NodeStatus, PhysicsScene, PhysicsState, SkeletonInfo, SkeletonModel, SkeletonPose, array)

JOINT_NAMES = ["pelvis", "spine", "neck", "head", "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow",
               "r_wrist", "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle"]
JOINT_PARENT = np.array([-1, 0, 1, 2, 2, 4, 5, 2, 7, 8, 0, 10, 11, 0, 13, 14], np.int32)
# Rest pose facing +X (Y to the performer's left, Z up), m.
REST = np.array([
    [0, 0, 0.95], [0, 0, 1.20], [0, 0, 1.45], [0, 0, 1.65],
    [0, 0.19, 1.42], [0, 0.22, 1.14], [0.03, 0.22, 0.88],
    [0, -0.19, 1.42], [0, -0.22, 1.14], [0.03, -0.22, 0.88],
    [0, 0.10, 0.92], [0.02, 0.10, 0.50], [0, 0.10, 0.08],
    [0, -0.10, 0.92], [0.02, -0.10, 0.50], [0, -0.10, 0.08]])
_LEGS = ((10, [11, 12], 11, [12]), (13, [14, 15], 14, [15]))  # hip, below hip, knee, below knee
_ARMS = ((4, [5, 6], 5, [6]), (7, [8, 9], 8, [9]))
STEP_HZ = 0.9


def _pitch(points: np.ndarray, pivot: np.ndarray, angle: float) -> np.ndarray:
    """Rotate points about the Y axis through ``pivot`` by ``angle`` rad."""
    c, s = math.cos(angle), math.sin(angle)
    d = points - pivot
    return pivot + np.stack([c * d[:, 0] + s * d[:, 2], d[:, 1], -s * d[:, 0] + c * d[:, 2]], axis=1)


def performer_joints(t: float, center: tuple[float, float] = (0.0, 0.0), radius: float = 1.2,
                     phase: float = 0.0) -> tuple[np.ndarray, float]:
    """Joint centres (J, 3) of the performer at time ``t`` s walking a circle, m world; and its heading, rad."""
    p = REST.copy()
    swing = 2 * math.pi * STEP_HZ * t + phase
    for k, (hip, below, knee, below_knee) in enumerate(_LEGS):
        a = 0.45 * math.sin(swing + k * math.pi)
        p[below] = _pitch(p[below], p[hip], a)
        p[below_knee] = _pitch(p[below_knee], p[knee], -0.6 * max(0.0, math.sin(swing + k * math.pi + 1.2)))
    for k, (sh, below, el, below_el) in enumerate(_ARMS):
        a = -0.35 * math.sin(swing + k * math.pi)
        p[below] = _pitch(p[below], p[sh], a)
        p[below_el] = _pitch(p[below_el], p[el], -0.5)
    p[:, 2] += 0.025 * math.cos(2 * swing)
    theta = 2 * math.pi * 0.08 * t + phase
    heading = theta + math.pi / 2
    rot = Rotation.from_euler("z", heading).as_matrix()
    pos = np.array([center[0] + radius * math.cos(theta), center[1] + radius * math.sin(theta), 0.0])
    return p @ rot.T + pos, heading


_ONE_CHILD = np.array([j for j in range(len(JOINT_NAMES)) if (JOINT_PARENT == j).sum() == 1])
_ITS_CHILD = np.array([int(np.flatnonzero(JOINT_PARENT == j)[0]) for j in _ONE_CHILD])


def performer_local_rotations(joints: np.ndarray, heading: float) -> np.ndarray:
    """Local rotations (J, 4) wxyz whose forward kinematics from REST (rest rotations identity, the
    root at ``joints[0]``) give ``joints``: every joint turned by the heading, a joint with one
    child also swung (shortest arc) onto its posed bone; the rigid torso and the leaves only turned."""
    J = len(JOINT_NAMES)
    yaw = Rotation.from_euler("z", heading)
    rest = yaw.apply(REST[_ITS_CHILD] - REST[_ONE_CHILD])
    posed = joints[_ITS_CHILD] - joints[_ONE_CHILD]
    axis = np.cross(rest, posed)
    sin = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sin, np.einsum("ij,ij->i", rest, posed))
    rotvec = np.where((sin > 1e-12)[:, None] & np.isfinite(axis), axis / np.maximum(sin, 1e-12)[:, None] * angle[:, None], 0.0)
    world = np.tile(yaw.as_quat(), (J, 1))
    world[_ONE_CHILD] = (Rotation.from_rotvec(rotvec) * yaw).as_quat()
    for j in range(J):   # parents precede children: a leaf keeps its parent's orientation
        if (JOINT_PARENT == j).sum() == 0 and JOINT_PARENT[j] >= 0:
            world[j] = world[JOINT_PARENT[j]]
    parent_world = Rotation.from_quat(np.where((JOINT_PARENT >= 0)[:, None], world[np.maximum(JOINT_PARENT, 0)],
                                               [0.0, 0.0, 0.0, 1.0]))
    return (parent_world.inv() * Rotation.from_quat(world)).as_quat(scalar_first=True)


def marker_offsets(n: int) -> np.ndarray:
    """Offsets (n, 3) of marker i from its joint (i mod J), on a 6 cm sphere (golden-angle spiral), m."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = i * math.pi * (3 - math.sqrt(5))
    return 0.06 * np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def marker_state(frame: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(missing, unseen) masks for frame ``frame``: missing markers are NaN, unseen ones are predicted (red)."""
    block = frame // 24 + np.arange(n)
    return block % 11 == 0, block % 13 == 5


class StagePerformer(Node):
    """A procedural walking performer published as the message types the viewer draws."""

    summary = "procedural performer for the viewer's tests and demos (markers, actor, skeleton, character, physics)"
    rate_hz = Param(120.0, "frames per second, Hz", minimum=0.1)
    actor = Param("actor_1", "actor / source / character name")
    n_markers = Param(60, "markers per frame", minimum=1)
    center = Param([0.0, 0.0], "centre of the walked circle, m")
    radius = Param(1.2, "radius of the walked circle, m", minimum=0.0)
    phase = Param(0.0, "phase of the walk, rad")
    publish = Param(["markers", "actor"], "what to publish: markers, actor, skeleton, character, physics")
    nan_joint = Param(-1, "joint index published as NaN on odd seconds (-1: none)")
    count = Param(0, "frames to send before stopping; 0 sends forever", minimum=0)

    STREAMS = {
        "markers": (("markers", "markers", MarkerFrame), ("marker_layout", "marker_layout", MarkerLayout)),
        "actor": (("actor_pose", "actor_pose", ActorPose), ("skeleton_model", "skeleton_model", SkeletonModel)),
        "skeleton": (("skeleton_pose", "skeleton_pose", SkeletonPose), ("skeleton_info", "skeleton_info",
                                                                         SkeletonInfo)),
        "character": (("character_pose", "character_pose", CharacterPose), ("character_info", "character_info",
                                                                             CharacterInfo)),
        "physics": (("physics_state", "physics_state", PhysicsState), ("physics_scene", "physics_scene",
                                                                       PhysicsScene)),
    }

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        for what in params.get("publish", cls.publish.default):
            for port, topic, mtype in cls.STREAMS.get(what, ()):
                iface.outputs[port] = Output(topic, mtype, f"{what} of the performer", name=port)
        return iface

    def on_start(self) -> None:
        self.frame = 0
        self.offsets = marker_offsets(self.n_markers)
        self.marker_joint = np.arange(self.n_markers) % len(JOINT_NAMES)
        what = self.publish
        J = len(JOINT_NAMES)
        if "markers" in what:
            self.bound_port("marker_layout").publish(MarkerLayout(
                name="stage_performer", labels=[f"{self.actor}:M{i:02d}" for i in range(self.n_markers)],
                limb_names=JOINT_NAMES, marker_limb=self.marker_joint, units_note="generated in metres, world",
                source="stage performer"))
        if "actor" in what:
            bone = np.linalg.norm(REST - REST[np.maximum(JOINT_PARENT, 0)], axis=1)
            bone[JOINT_PARENT < 0] = np.nan
            M = self.n_markers
            self.bound_port("skeleton_model").publish(SkeletonModel(
                layout_name="stage_performer", fingerprint="", marker_labels=[f"M{i:02d}" for i in range(M)],
                limb_names=JOINT_NAMES, joint_names=JOINT_NAMES, marker_limb=self.marker_joint,
                limb_parent=JOINT_PARENT, joint_limbs=np.stack([np.maximum(JOINT_PARENT, 0), np.arange(J)], 1),
                joint_parent=JOINT_PARENT, joint_hinge=np.isin(np.arange(J), [5, 8, 11, 14]),
                base_markers=REST[self.marker_joint] + self.offsets, joint_offsets=np.zeros((J, 2, 3)),
                base_joints=REST, bone_lengths=bone, hinge_axes=np.full((J, 3), np.nan),
                joint_residual_rms=0.001 + 0.0013 * (np.arange(J) % 9), joint_rom=np.linspace(0.2, 1.8, J)))
        if "skeleton" in what:
            self.bound_port("skeleton_info").publish(SkeletonInfo(
                source="stage_performer", joint_names=JOINT_NAMES, joint_parent=JOINT_PARENT,
                rest_offsets=REST - REST[np.maximum(JOINT_PARENT, 0)], units_note="generated in metres, world"))
        if "character" in what:
            self.bound_port("character_info").publish(CharacterInfo(
                character=self.actor, joint_names=JOINT_NAMES, joint_parent=JOINT_PARENT,
                rest_offsets=REST - REST[np.maximum(JOINT_PARENT, 0)], rest_rotations=np.tile([1.0, 0, 0, 0], (J, 1))))
        if "physics" in what:
            self.bound_port("physics_scene").publish(PhysicsScene(
                body_names=["crate", "ball", "torso", "l_thigh", "r_thigh"],
                shapes=["box", "sphere", "capsule", "capsule", "capsule"],
                sizes=[[0.3, 0.3, 0.3], [0.12, 0, 0], [0.12, 0.2, 0], [0.07, 0.2, 0], [0.07, 0.2, 0]]))
        self.add_timer(1.0 / self.rate_hz, self.tick, first_delay_s=0.0)

    def tick(self) -> None:
        f = self.frame
        t = f / self.rate_hz
        joints, heading = performer_joints(t, tuple(self.center), self.radius, self.phase)
        now = time.time_ns()
        what = self.publish
        J = len(joints)
        if self.nan_joint >= 0 and int(t) % 2 == 1:
            joints[self.nan_joint] = np.nan
        if "markers" in what:
            rot = Rotation.from_euler("z", heading).as_matrix()
            pos = joints[self.marker_joint] + self.offsets @ rot.T
            missing, unseen = marker_state(f, self.n_markers)
            pos[missing] = np.nan
            valid = ~(missing | unseen)
            self.bound_port("markers").publish(MarkerFrame(
                frame_number=f, rate_hz=self.rate_hz, positions=pos, valid=valid,
                residual=np.where(valid, 0.0005, np.nan).astype(np.float32)), capture_ns=now)
        if "actor" in what:
            q = np.full(J, QUALITY_GOOD, np.int8)
            q[(f // 60 + np.arange(J)) % 7 == 0] = QUALITY_ESTIMATED
            q[np.isnan(joints[:, 0])] = QUALITY_MISSING
            quat = np.tile([1.0, 0, 0, 0], (J, 1))
            self.bound_port("actor_pose").publish(ActorPose(
                actor=self.actor, frame_number=f, joint_positions=joints, joint_quality=q, limb_orientations=quat,
                limb_quality=q, limb_visible_markers=np.full(J, 3, np.int16)), capture_ns=now)
        if "skeleton" in what:
            state = np.full(J, TRACK_TRACKED, np.int8)
            if int(t) % 2 == 0:
                state[[6, 9]] = TRACK_INFERRED
            quat = np.tile(Rotation.from_euler("z", heading).as_quat(scalar_first=True), (J, 1))
            self.bound_port("skeleton_pose").publish(SkeletonPose(
                source_id=self.actor, frame_number=f, joint_positions=joints, joint_orientations=quat,
                tracking_state=state), capture_ns=now)
        if "character" in what:
            quat = performer_local_rotations(joints, heading)
            self.bound_port("character_pose").publish(CharacterPose(
                character=self.actor, frame_number=f, root_position=joints[0], local_rotations=quat,
                joint_positions=joints, joint_quality=np.full(J, 2, np.int8)), capture_ns=now)
        if "physics" in what:
            self._publish_physics(t, joints, heading, now)
        self.frame += 1
        if self.count and self.frame >= self.count:
            self.request_stop()

    def _publish_physics(self, t: float, joints: np.ndarray, heading: float, now: int) -> None:
        ball_z = 0.12 + abs(math.sin(2.2 * t)) * 0.9
        thighs = [(joints[10] + joints[11]) / 2, (joints[13] + joints[14]) / 2]
        pos = np.array([[2.2, -1.6, 0.3], [2.0, 1.5, ball_z], (joints[0] + joints[2]) / 2, *thighs])
        yaw = Rotation.from_euler("z", heading)
        quats = np.array([Rotation.from_euler("z", 0.4).as_quat(scalar_first=True),
                          [1.0, 0, 0, 0]] + [yaw.as_quat(scalar_first=True)] * 3)
        err = np.array([np.nan, np.nan, 0.01, 0.03 + 0.03 * math.sin(t), 0.08])
        self.bound_port("physics_state").publish(PhysicsState(sim_time_s=t, positions=pos, orientations=quats,
                                                          tracking_error=err), capture_ns=now)


CALIBRATION_STEPS = {  # command -> (states it is allowed in, state it leads to)
    "find_base_pose": (("idle", "base_pose_found", "gym_captured", "calibrated", "failed"), "base_pose_found"),
    "capture_gym": (("base_pose_found", "gym_captured", "calibrated"), "capturing_gym"),
    "process": (("gym_captured",), "calibrated"),
}


class CommandEcho(Node):
    """A small real state machine driven by NodeCommand, reporting NodeStatus (calibration or player role)."""

    summary = "state machine answering NodeCommand with NodeStatus (viewer tests and demos)"
    role = Param("calibration", "calibration or player", choices=("calibration", "player"))
    gym_s = Param(1.0, "calibration: how long 'capturing_gym' lasts, s", minimum=0.0)
    duration_s = Param(30.0, "player: length of the pretend recording, s", minimum=0.1)
    step_s = Param(1 / 120, "player: one step, s", minimum=1e-6)
    status_hz = Param(5.0, "periodic status rate, Hz", minimum=0.1)

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        role = params.get("role", cls.role.default)
        iface.inputs["command"] = Input(f"{role}_command", NodeCommand, f"{role} commands", required=False,
                                        name="command")
        iface.outputs["status"] = Output(f"{role}_status", NodeStatus, f"{role} state", name="status")
        return iface

    def on_start(self) -> None:
        self.state = "idle" if self.role == "calibration" else "paused"
        self.detail = ""
        self.t = 0.0
        self.t_mark = time.monotonic()
        self.gym_started = 0.0
        self.add_timer(1.0 / self.status_hz, self.report, first_delay_s=0.0)
        self.add_timer(0.05, self.advance)

    def on_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name):
            return
        try:
            args = parse_command(cmd.command, cmd.args_json, CALIBRATION_COMMANDS if self.role == "calibration"
                                 else PLAYER_COMMANDS)
        except ValueError as exc:  # reported like the real nodes do, never a traceback
            self.detail = str(exc)
            self.report()
            return
        if self.role == "calibration":
            allowed, nxt = CALIBRATION_STEPS.get(cmd.command, ((), ""))
            if self.state not in allowed:
                self.detail = f"cannot {cmd.command} in state {self.state}"
            else:
                self.state, self.detail = nxt, f"{cmd.command} accepted"
                self.gym_started = time.monotonic()
        else:
            self._position()
            if cmd.command == "play":
                self.state = "playing"
            elif cmd.command == "pause":
                self.state = "paused"
            elif cmd.command == "step":
                self.state, self.t = "paused", min(self.duration_s, self.t + self.step_s)
            elif cmd.command == "seek":
                self.t = float(np.clip(float(args.get("position_s", 0.0)), 0.0, self.duration_s))
            self.detail = f"{cmd.command} accepted"
        self.report()

    def _position(self) -> float:
        now = time.monotonic()
        if self.state == "playing":
            self.t = min(self.duration_s, self.t + now - self.t_mark)
        self.t_mark = now
        return self.t

    def advance(self) -> None:
        if self.role == "calibration" and self.state == "capturing_gym":
            if time.monotonic() - self.gym_started >= self.gym_s:
                self.state, self.detail = "gym_captured", "gym motion captured"
                self.report()
        elif self.role == "player":
            self._position()
            if self.state == "playing" and self.t >= self.duration_s:
                self.state = "finished"
                self.report()

    def report(self) -> None:
        if self.role == "calibration":
            progress = {"idle": 0.0, "base_pose_found": 0.25, "gym_captured": 0.75, "calibrated": 1.0}.get(
                self.state, min(0.75, 0.25 + 0.5 * (time.monotonic() - self.gym_started) / max(self.gym_s, 1e-6)))
            data: dict[str, Any] = {"step": self.state}
            if self.state == "calibrated":
                # the real calibration node's report (mocapgraph.nodes.model_messages.quality_report)
                data["joints"] = [{"joint": n, "residual_mm": 2.0, "rom_deg": 60.0, "reliable": bool(i % 5),
                                   "warnings": [] if i % 5 else ["move this joint more"]}
                                  for i, n in enumerate(JOINT_NAMES)]
        else:
            progress = self._position() / self.duration_s
            data = {"position_s": self.t, "duration_s": self.duration_s}  # as the bag player reports
        self.bound_port("status").publish(NodeStatus(node=self.name, state=self.state, detail=self.detail,
                                                 progress=progress, data_json=json.dumps(data)))


class ForcePlateSample(Message):
    """Ground reaction forces of force plates (a type the viewer page does not know; for its tests)."""

    type_name = "ForcePlateSample"
    version = 1
    force = array("float64", ("P", 3), "force on each plate, N, world")
    cop = array("float64", ("P", 3), "centre of pressure, m, world")


class ForcePlateSource(Node):
    """Publishes ForcePlateSample on ``force_plates`` at a fixed rate."""

    summary = "force plate samples of a type the viewer does not draw (viewer tests)"
    out = Output("force_plates", ForcePlateSample, "force plate samples")
    rate_hz = Param(50.0, "samples per second, Hz", minimum=0.1)

    def on_start(self) -> None:
        self.add_timer(1.0 / self.rate_hz, self.tick, first_delay_s=0.0)

    def tick(self) -> None:
        self.out.publish(ForcePlateSample(force=[[0.0, 0.0, 700.0], [0.0, 0.0, 0.0]],
                                          cop=[[0.5, 0.2, 0.0], [np.nan, np.nan, np.nan]]))
