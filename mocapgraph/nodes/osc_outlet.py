"""OSC outlet node: joint positions and rotations to a host and port, one address per joint.

For TouchDesigner, Max/MSP, Unity and Blender live links. Each frame of each actor, character or
skeleton stream is one OSC bundle over UDP (addresses in :mod:`mocapgraph.formats.osc_frames`):
``/<prefix>/<kind>/<name>/<joint>/position|rotation|quality`` and ``/<prefix>/<kind>/<name>/frame``
(kind: actor, character, skeleton).
Rotations by source: actors, the world rotation of the limb below the joint relative to its
base pose; characters, the local rotation relative to the rest pose in the parent's frame;
skeleton streams (Kinect, BVH), the joint's world orientation. All quaternions w, x, y, z.
Joint names come from the latched SkeletonModel, CharacterInfo or SkeletonInfo; frames that
arrive before their names are skipped (counted in the log).
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..bus import Input, Node, Param
from ..bus.node import NodeConfigError
from ..formats.osc_frames import JointBundle
from ..messages import ActorPose, CharacterInfo, CharacterPose, SkeletonInfo, SkeletonModel, SkeletonPose
from ..messages.pose_quality import character_quality
from ..net.datagram_out import DatagramOut, HostError


class OSCOutlet(Node):
    """Sends every actor, character and skeleton frame as an OSC bundle of per-joint messages."""

    summary = "OSC (UDP) joint positions/rotations per joint address, for TouchDesigner, Max, Unity, Blender"

    actor_pose = Input("actor_pose", ActorPose, "solved actors", required=False)
    skeleton_model = Input("skeleton_model", SkeletonModel, "actor joint names", latched=True, required=False)
    character_pose = Input("character_pose", CharacterPose, "retargeted characters", required=False)
    character_info = Input("character_info", CharacterInfo, "character joint names", latched=True, required=False)
    skeleton_pose = Input("skeleton_pose", SkeletonPose, "Kinect/BVH skeleton streams", required=False)
    skeleton_info = Input("skeleton_info", SkeletonInfo, "skeleton joint names", latched=True, required=False)

    host = Param("127.0.0.1", "receiver address (the machine running TouchDesigner, Max, Unity...)")
    port = Param(9000, "receiver UDP port", minimum=1, maximum=65535)
    prefix = Param("mocap", "first address part: /<prefix>/<actor|character|skeleton>/<name>/<joint>/...")
    max_rate_hz = Param(0.0, "most bundles per second per stream, Hz; 0 sends every frame", minimum=0.0)
    send_missing = Param(False, "send missing joints as NaN instead of leaving their position/rotation out")

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Any = None) -> None:
        super().__init__(name, params, wiring)
        try:
            self.out = DatagramOut(self.host, self.port, self.log, "OSC")
        except HostError as exc:
            raise NodeConfigError(str(exc)) from None
        self.models: list[SkeletonModel] = []
        self.characters: dict[str, CharacterInfo] = {}
        self.skeletons: list[SkeletonInfo] = []
        self.bundles: dict[tuple[str, str, tuple[str, ...]], JointBundle] = {}
        self._last_sent: dict[str, float] = {}
        self.skipped = 0

    # ----- names ---------------------------------------------------------------------------------
    def on_skeleton_model(self, msg: SkeletonModel) -> None:
        self.models = [m for m in self.models if len(m.joint_names) != len(msg.joint_names)] + [msg]

    def on_character_info(self, msg: CharacterInfo) -> None:
        self.characters[msg.character] = msg

    def on_skeleton_info(self, msg: SkeletonInfo) -> None:
        self.skeletons = [s for s in self.skeletons if len(s.joint_names) != len(msg.joint_names)] + [msg]

    # ----- frames ---------------------------------------------------------------------------------
    def on_actor_pose(self, msg: ActorPose) -> None:
        J = len(msg.joint_positions)
        model = next((m for m in reversed(self.models) if len(m.joint_names) == J), None)
        if model is None:
            return self._skip("actor_pose", msg.actor)
        # the limb below each joint carries its rotation (NaN where that limb is missing)
        distal = np.asarray(model.joint_limbs)[:, 1]
        rot = None
        if len(msg.limb_orientations) > distal.max(initial=-1):
            rot = msg.limb_orientations[distal].copy()
            rot[msg.limb_quality[distal] == 0] = np.nan  # a missing limb's rotation is not sent
        self._send("actor", msg.actor, model.joint_names, msg.frame_number, msg.joint_positions, rot,
                   msg.joint_quality, "actor_pose")

    def on_character_pose(self, msg: CharacterPose) -> None:
        info = self.characters.get(msg.character)
        if info is None or len(info.joint_names) != len(msg.joint_positions):
            return self._skip("character_pose", msg.character)
        self._send("character", msg.character, info.joint_names, msg.frame_number, msg.joint_positions,
                   msg.local_rotations, character_quality(msg), "character_pose")

    def on_skeleton_pose(self, msg: SkeletonPose) -> None:
        J = len(msg.joint_positions)
        info = next((s for s in reversed(self.skeletons) if len(s.joint_names) == J), None)
        if info is None:
            return self._skip("skeleton_pose", msg.source_id)
        self._send("skeleton", msg.source_id, info.joint_names, msg.frame_number, msg.joint_positions,
                   msg.joint_orientations, msg.tracking_state, "skeleton_pose")

    def _skip(self, port: str, who: str) -> None:
        self.skipped += 1
        if self.skipped in (1, 10, 100) or self.skipped % 1000 == 0:
            self.log.warning("%s %s: joint names not known yet (no latched message); %d frames skipped",
                             port, who, self.skipped)

    def _send(self, kind: str, who: str, joints: list[str], frame: int, pos: np.ndarray, rot: np.ndarray | None,
              quality: np.ndarray, port: str) -> None:
        stream = f"{kind}/{who}"
        if self.max_rate_hz > 0:
            now = time.monotonic()
            if now - self._last_sent.get(stream, -1e9) < 1.0 / self.max_rate_hz:
                return
            self._last_sent[stream] = now
        key = (kind, who, tuple(joints))
        bundle = self.bundles.get(key)
        if bundle is None:
            bundle = self.bundles[key] = JointBundle(self.prefix, kind, who, list(joints), self.send_missing)
            self.log.info("OSC %s to %s:%d under %s (%d joints)", stream, self.host, self.port,
                          bundle.addresses["frame"].rsplit("/", 1)[0], len(joints))
        env = self._ports[port].envelope
        data = bundle.encode(frame, pos, rot, np.asarray(quality), env.capture_ns * 1e-9)
        self.out.send(data)

    def on_stop(self) -> None:
        self.log.info("%d OSC bundles sent, %d frames skipped, %d send errors", self.out.sent, self.skipped,
                      self.out.send_errors)
        self.out.close()
