"""VMC outlet node: retargeted characters to VSeeFace, Unity, Unreal and Blender over the VMC protocol.

One OSC bundle per ``character_pose`` (the pose rate) to ``host:port`` (default 39539, where VMC
receivers listen): ``/VMC/Ext/OK``, ``/VMC/Ext/T``, ``/VMC/Ext/Root/Pos`` and one
``/VMC/Ext/Bone/Pos`` per Unity humanoid bone the character has, in Unity's axes, rotations
relative to the rest pose (:mod:`mocapgraph.formats.vmc` does the math). The character's skeleton
comes from the latched ``character_info``; poses before it are skipped (counted). With several
characters on the topic, ``character`` picks one (VMC drives one avatar per port).
"""
from __future__ import annotations

from typing import Any


from ..bus import Input, Node, Param
from ..bus.node import NodeConfigError
from ..messages import CharacterInfo, CharacterPose
from ..messages.pose_quality import character_quality
from ..net.datagram_out import DatagramOut, HostError


class VMCOutlet(Node):
    """Sends each character pose as one VMC bundle (root, bones, availability, time)."""

    summary = "VMC protocol (OSC/UDP) humanoid bones for VSeeFace, Unity (EVMC4U), Unreal (VMC4UE), Blender (VMC4B)"

    character_pose = Input("character_pose", CharacterPose, "retargeted characters")
    character_info = Input("character_info", CharacterInfo, "character skeletons", latched=True)

    host = Param("127.0.0.1", "receiver address (the machine running VSeeFace, Unity, Unreal, Blender)")
    port = Param(39539, "receiver UDP port (39539: a VMC 'Marionette')", minimum=1, maximum=65535)
    character = Param("", "the character to send (empty: the first one seen)")
    bones = Param({}, "Unity bone -> joint table, e.g. {Hips: pelvis, Spine: spine_01}; empty: the shipped "
                      "table naming most of the character's joints (mixamo, cmu, standard_20, unity names)")
    avatar = Param("", "a .vrm/.glb/.gltf file whose VRM humanoid map names the bones (the character loaded from it)")

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Any = None) -> None:
        super().__init__(name, params, wiring)
        if not isinstance(self.bones, dict):
            raise NodeConfigError(f"bones: wants a mapping Unity bone -> joint, got {self.bones!r}")
        self._bones = {str(b): str(j) for b, j in self.bones.items()}
        from ..formats.vmc import UNITY_BONES
        unknown = sorted(b for b in self._bones if b not in UNITY_BONES)
        if unknown:
            raise NodeConfigError(f"bones: {', '.join(unknown[:3])} are not Unity humanoid bones "
                                  "(Hips, Spine, Chest, LeftUpperArm, ...)")
        if self.avatar and not self._bones:
            from ..formats.gltf_character import GltfCharacterError, load_gltf_character
            try:
                from ..formats.vmc import UNITY_BONES
                self._bones = {b: j for b, j in load_gltf_character(self.avatar).humanoid.items() if b in UNITY_BONES}
            except (GltfCharacterError, OSError) as exc:
                raise NodeConfigError(f"avatar: {exc}") from None
            if not self._bones:
                raise NodeConfigError(f"avatar: {self.avatar} has no VRM humanoid map (give `bones`)")
        try:
            self.out = DatagramOut(self.host, self.port, self.log, "VMC")
        except HostError as exc:
            raise NodeConfigError(str(exc)) from None
        self.templates: dict[str, Any] = {}   # character -> VMCBundle, or an error text
        self._t0_ns: int | None = None
        self._only = self.character
        self.skipped = 0

    def on_character_info(self, msg: CharacterInfo) -> None:
        from ..formats.vmc import VMCBundle, VMCError
        from ..retarget.character import Character, CharacterError
        if self.character and msg.character != self.character:
            return
        try:
            ch = Character(msg.character, tuple(msg.joint_names), msg.joint_parent, msg.rest_offsets,
                           msg.rest_rotations, allow_zero_bones=True)
            bundle = VMCBundle(ch, self._bones or None)
        except (CharacterError, VMCError) as exc:
            self.templates[msg.character] = str(exc)
            self.log.error("character %s: %s; its poses are not sent", msg.character, exc)
            return
        self.templates[msg.character] = bundle
        self.log.info("VMC %s to %s:%d: %d humanoid bones (%s)", msg.character, self.host, self.port,
                      len(bundle.bone_names), ", ".join(b for b in bundle.bone_names[:6]) + ", ...")

    def on_character_pose(self, msg: CharacterPose) -> None:
        if self._only and msg.character != self._only:
            return
        self._only = msg.character   # VMC drives one avatar: the first one seen
        bundle = self.templates.get(msg.character)
        if bundle is None or isinstance(bundle, str) or len(msg.local_rotations) != bundle.character.n_joints:
            self.skipped += 1
            if self.skipped in (1, 10, 100) or self.skipped % 1000 == 0:
                why = bundle if isinstance(bundle, str) else "no character_info that fits yet"
                self.log.warning("character_pose %s: %s; %d poses skipped", msg.character, why, self.skipped)
            return
        env = self._ports["character_pose"].envelope
        if self._t0_ns is None:
            self._t0_ns = env.capture_ns
        data = bundle.encode(msg.local_rotations, msg.root_position, character_quality(msg),
                             (env.capture_ns - self._t0_ns) * 1e-9)
        self.out.send(data)

    def on_stop(self) -> None:
        self.log.info("%d VMC bundles sent, %d poses skipped, %d send errors", self.out.sent, self.skipped,
                      self.out.send_errors)
        self.out.close()


