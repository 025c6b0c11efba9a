"""Retargeter node: the performer's motion on a character, one CharacterPose per source frame.

``source: actor`` takes ``actor_pose`` with the latched ``skeleton_model`` (the optical pipeline);
``source: skeleton`` takes ``skeleton_pose`` with the latched ``skeleton_info`` (Kinect, BVH). The
character comes from a file or a shipped name, the mapping from a file or, when empty, derived from
the two rest poses (``mapping_out`` writes it for editing). Publishes the latched
``character_info`` and ``character_pose``; ``retarget_status`` says what it is doing. Commands on
``retarget_command``: ``capture_rest_pose`` (the performer stands in the character's rest pose now;
written to ``mapping_out`` when set) and ``reset``. A mapping that does not fit the stream (wrong
skeleton, missing joints) is one logged error and the node waits for a stream that fits; a frame
with fewer joints than the latched definition is counted and skipped; missing joints are held and
flagged. Several characters from one performer are several nodes.
"""
from __future__ import annotations

import json
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from ..bus import Input, Node, Output, Param
from ..bus.bound_ports import COPY_BELOW
from ..bus.file_places import PathRefused, own_folder_path
from ..bus.node import NodeConfigError
from ..messages import (ActorPose, CharacterInfo, CharacterPose, NodeCommand, NodeStatus, SkeletonInfo,
                        SkeletonModel, SkeletonPose)

from ..messages.commands import RETARGET_COMMANDS as COMMANDS

if TYPE_CHECKING:   # the math (scipy, numba) is imported when the node is built (see __init__)
    from ..retarget.retargeter import RetargetOptions


def _check_offset(params: dict) -> None:
    """The ``offset`` param (padded to 3, as the node uses it): finite, within the room."""
    from ..retarget.character import CharacterError, checked_shift
    try:
        checked_shift((list(params.get("offset") or []) + [0.0, 0.0, 0.0])[:3], "parameter 'offset'")
    except CharacterError as exc:
        raise NodeConfigError(str(exc)) from None


class RetargeterNode(Node):
    """Source frames in, character frames out (retarget.retargeter does the work)."""

    summary = "the performer on a character (Kiip/Claro retargeting, foot planting) -> CharacterPose"
    actor_pose = Input("actor_pose", ActorPose, "solved actor frames (source: actor)")
    skeleton_model = Input("skeleton_model", SkeletonModel, "latched actor model (source: actor)", latched=True)
    skeleton_pose = Input("skeleton_pose", SkeletonPose, "skeleton frames (source: skeleton)")
    skeleton_info = Input("skeleton_info", SkeletonInfo, "latched skeleton definition (source: skeleton)",
                          latched=True)
    retarget_command = Input("retarget_command", NodeCommand, "capture_rest_pose, reset; target '' or this node",
                             required=False)
    character_info = Output("character_info", CharacterInfo, "latched character skeleton")
    character_pose = Output("character_pose", CharacterPose, "retargeted character, one per source frame")
    retarget_status = Output("retarget_status", NodeStatus, "state and detail", latched=True)

    source = Param("actor", "what drives the character: 'actor' (ActorPose + SkeletonModel) or 'skeleton' "
                   "(SkeletonPose + SkeletonInfo)", choices=("actor", "skeleton"))
    character = Param("standard_20", "character file (YAML or BVH) or shipped name (graph_configs/characters)")
    character_name = Param("", "name published in CharacterInfo/CharacterPose (default: the character's)")
    height_m = Param(0.0, "height of a generated character (standard_20), m; 0 keeps the file's", minimum=0.0)
    mapping = Param("", "mapping file or shipped name (graph_configs/mappings); empty: derived automatically")
    mapping_out = Param("", "write the derived or captured mapping here (YAML, editable)")
    scale = Param(0.0, "root translation ratio; 0: the mapping's, else the leg-length ratio", minimum=0.0)
    spread = Param(True, "spread the spine/neck over the character's joints (Kiip 3.5.3)")
    aim = Param(True, "aim clavicles at the shoulders (Kiip 3.5.4)")
    roll = Param(True, "roll joints share the limb twist (Kiip 3.5.5)")
    follow_bones = Param(True, "one-child joints point their bone along the source bone")
    follow_tolerance_deg = Param(10.0, "a joint whose bone turns from the source bone by more than this beyond the "
                                       "rest-shape difference is flagged estimated on that frame, deg (180: never)",
                                 minimum=0.0, maximum=180.0)
    foot_planting = Param(True, "feet in contact stay put and above the floor (Kiip 3.5.6)")
    root_scale = Param(True, "scale the root translation by the leg-length ratio")
    floor_z = Param(0.0, "floor height, m")
    keep_up = Param(False, "when frames come faster than they are retargeted, take only the newest (bounded latency "
                           "for live viewing; the skipped frames are not retargeted)")
    offset = Param([0.0, 0.0, 0.0], "world shift of the character, m, e.g. [0, -1.2, 0] stands it beside the performer")

    @classmethod
    def interface(cls, params: dict[str, Any]):
        iface = super().interface(params)
        drop = ("skeleton_pose", "skeleton_info") if params.get("source", "actor") == "actor" \
            else ("actor_pose", "skeleton_model")
        for k in drop:
            iface.inputs.pop(k, None)
        if params.get("keep_up", False):
            from dataclasses import replace
            for k in ("actor_pose", "skeleton_pose"):
                if k in iface.inputs:
                    iface.inputs[k] = replace(iface.inputs[k], latest_only=True)
        return iface

    @classmethod
    def graph_check(cls, params: dict) -> None:
        """The check refuses a character file this node would refuse (file:line) and a shift that
        is not a place in the room (1e300), before MuJoCo or a drawing meets them."""
        from ..formats.character_file import CharacterFileError, load_character
        _check_offset(params)
        try:
            load_character(str(params.get("character", cls.character.default)))
        except CharacterFileError as exc:
            raise NodeConfigError(f"parameter 'character': {exc}") from None

    def __init__(self, name: str, params: dict | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        _check_offset(self.params)
        try:  # written later: a regular file in the folder the graph names, never a device or elsewhere
            self.mapping_out and own_folder_path(self.mapping_out, "parameter 'mapping_out'")
        except PathRefused as exc:
            raise NodeConfigError(str(exc)) from None
        self.rig = None
        self._rg_definition: tuple | None = None     # what the retargeter was built for
        self._rg_refused: str | None = None
        self._rg_bad_frames = 0
        self._rg_t0: int | None = None
        self._rg_frames = 0
        self._rg_dims: tuple[int, int] | None = None   # (joints, limbs) of the latched actor model
        # the retargeter whose one-frame buffers _rg_out are, and the message that publishes them
        self._rg_out_for = self._rg_out = self._rg_message = None
        # the math and the compiled kernels now, not at the first model or frame (which would queue
        # ~0.4 s of frames behind them), nor with this module, which the launcher imports to check a
        # graph against the declarations above (scipy and numba would cost each check ~0.9 s of CPU)
        from ..formats import mapping_file, retarget_setup  # noqa: F401
        from ..retarget import kernels, warmup
        kernels.load()
        if self.source == "skeleton":   # rotations from a positions-only stream (Kinect)
            warmup.warm_source_kernels()

    # ----- status -------------------------------------------------------------------------------
    def _status(self, state: str, detail: str, data: dict | None = None, error: bool = False) -> None:
        (self.log.error if error else self.log.info)("%s", detail)
        self.retarget_status.publish(NodeStatus(node=self.name, state=state, detail=detail, progress=float("nan"),
                                                data_json=json.dumps(data or {})))

    def _options(self) -> RetargetOptions:
        from ..retarget.retargeter import RetargetOptions
        return RetargetOptions(spread=self.spread, aim=self.aim, roll=self.roll, follow_bones=self.follow_bones,
                               follow_tolerance_deg=float(self.follow_tolerance_deg),
                               foot_planting=self.foot_planting, root_scale=self.root_scale,
                               scale=self.scale or None, floor_z=self.floor_z,
                               offset=tuple(float(x) for x in (list(self.offset) + [0.0, 0.0, 0.0])[:3]))

    def _build(self, source, key: tuple, what: str) -> None:
        from ..formats.character_file import CharacterFileError
        from ..formats.retarget_setup import build
        from ..retarget.mapping import MappingError
        if self._rg_definition == key and self.rig is not None:
            return
        self.rig, self._rg_definition = None, key
        try:
            setup = build(self.character, self.mapping or None, source, self._options(), height_m=self.height_m or None,
                          write_derived=self.mapping_out or None)
        except (MappingError, CharacterFileError, ValueError, OSError) as exc:
            if self._rg_refused != str(exc):
                self._rg_refused = str(exc)
                self._status("error", f"cannot retarget {what}: {exc}; waiting for a stream that fits", error=True)
            return
        self._rg_refused = None
        self.rig = setup
        ch = setup.character
        self.character_info.publish(CharacterInfo(
            character=self.character_name or ch.name, joint_names=list(ch.joint_names),
            joint_parent=ch.parents.astype(np.int32), rest_offsets=ch.rest_offsets, rest_rotations=ch.rest_rotations))
        how = "derived mapping" if setup.derived else f"mapping {setup.mapping.file}"
        self._status("running", f"retargeting {what} onto {ch.name} ({ch.n_joints} joints, {how}, root ratio "
                                f"{setup.retargeter.ratio:.3f})",
                     {"character": ch.name, "mapped": [e.joint for e in setup.mapping.joints]})

    # ----- definitions --------------------------------------------------------------------------
    def on_skeleton_model(self, msg: SkeletonModel) -> None:
        from ..formats.retarget_setup import source_from_model
        src = source_from_model(msg.joint_names, msg.joint_parent, msg.joint_limbs, msg.limb_names, msg.base_joints,
                                msg.layout_name)
        self._rg_dims = (len(msg.joint_names), len(msg.limb_names))
        self._build(src, ("model", tuple(msg.joint_names), tuple(msg.limb_names), msg.base_joints.tobytes()),
                    f"actor of {len(msg.joint_names)} joints")

    def on_skeleton_info(self, msg: SkeletonInfo) -> None:
        self.rig, self._rg_definition = None, None    # built at the first pose (orientations or not)

    # ----- frames -------------------------------------------------------------------------------
    def _times(self, capture_ns: int) -> float:
        if self._rg_t0 is None:
            self._rg_t0 = capture_ns
        return (capture_ns - self._rg_t0) * 1e-9

    def on_skeleton_pose(self, msg: SkeletonPose) -> None:
        info = self.skeleton_info.latest
        if info is None:
            return
        J = len(info.joint_names)
        if msg.joint_positions.shape[0] != J:
            self._wrong(msg.frame_number, msg.joint_positions.shape[0], J)
            return
        has_q = bool(np.isfinite(msg.joint_orientations).any())
        if self.rig is None or self._rg_definition[1] != has_q:
            from ..formats.retarget_setup import source_from_skeleton_info
            src = source_from_skeleton_info(info.joint_names, info.joint_parent, info.rest_offsets, has_orientations=has_q)
            self._build(src, ("skeleton", has_q, tuple(info.joint_names), info.rest_offsets.tobytes()),
                        f"{info.source or 'skeleton'} ({J} joints{'' if has_q else ', positions only'})")
        if self.rig is None:
            return
        ok = msg.tracking_state >= 1
        res = self.rig.retargeter.process_one(msg.joint_positions, ok, msg.joint_orientations if has_q else None, None,
                                              self._times(self.skeleton_pose.envelope.capture_ns))
        self._publish(res, msg.frame_number, self.skeleton_pose.envelope.capture_ns)

    def on_actor_pose(self, msg: ActorPose) -> None:
        rig, dims = self.rig, self._rg_dims
        if rig is None or dims is None:
            return
        jp, rot = msg.joint_positions, msg.limb_orientations
        if jp.shape[0] != dims[0] or rot.shape[0] != dims[1]:
            self._wrong(msg.frame_number, jp.shape[0], dims[0])
            return
        capture_ns = self.actor_pose.envelope.capture_ns
        rt = rig.retargeter
        if self._rg_out_for is not rt:   # one frame's arrays, written in place by each frame (see _publish)
            out = rt.actor_buffers()
            if out is not None and max(a.nbytes for a in vars(out).values()) >= COPY_BELOW:
                out = None   # (a rig of thousands of joints: sent zero-copy, so new arrays each frame)
            self._rg_out_for, self._rg_out, self._rg_message = rt, out, None
        res = rt.process_actor(jp, msg.joint_quality, rot, msg.limb_quality, self._times(capture_ns), self._rg_out)
        self._publish(res, msg.frame_number, capture_ns)

    def _wrong(self, frame: int, got: int, want: int) -> None:
        self._rg_bad_frames += 1
        if self._rg_bad_frames <= 3 or self._rg_bad_frames % 1000 == 0:
            self._status("running", f"frame {frame} has {got} joints, the latched definition {want}: skipped "
                                    f"({self._rg_bad_frames} such frames)", error=True)

    def _publish(self, res, frame: int, capture_ns: int) -> None:
        """Publish one frame's result. A result written into the node's own buffers (``_rg_out``) goes
        out in one reused message whose arrays are those buffers: publishing sends copies (ZeroMQ
        copies frames below COPY_BELOW bytes, in-process subscribers get copies), so the next frame
        may overwrite them."""
        msg = self._rg_message
        if res is not self._rg_out or msg is None:
            msg = CharacterPose(
                character=self.character_name or self.rig.character.name, frame_number=int(frame),
                root_position=res.root_positions[0], local_rotations=res.local_rotations[0],
                joint_positions=res.joint_positions[0], joint_quality=res.joint_quality[0])
            if res is self._rg_out:
                self._rg_message = msg
        else:
            msg.frame_number = frame
        self.character_pose.publish(msg, capture_ns)
        self._rg_frames += 1

    # ----- commands -----------------------------------------------------------------------------
    def on_retarget_command(self, cmd: NodeCommand) -> None:
        if cmd.target not in ("", self.name):
            return
        if cmd.command not in COMMANDS:
            self._status("running" if self.rig else "waiting", f"unknown command {cmd.command!r} "
                         f"(expected one of {', '.join(COMMANDS)})", error=True)
            return
        if self.rig is None:
            self._status("waiting", f"{cmd.command}: no source stream yet", error=True)
            return
        from ..formats.mapping_file import write_mapping
        from ..retarget.mapping import MappingError
        rt = self.rig.retargeter
        if cmd.command == "reset":
            rt.reset()
            self._rg_t0 = None
            self._status("running", "reset: held joints and plants forgotten")
            return
        try:
            m = rt.set_rest_from_current()
        except MappingError as exc:
            self._status("running", str(exc), error=True)
            return
        self.rig.mapping = m
        where = ""
        if self.mapping_out:
            write_mapping(m, self.mapping_out, comment=f"rest pose captured live at {time.strftime('%Y-%m-%d %H:%M:%S')} "
                                                       f"onto {self.rig.character.name}")
            where = f", written to {self.mapping_out}"
        self._status("running", f"capture_rest_pose: the current pose is the character's rest pose{where}",
                     {"R": {e.joint: list(np.round(e.R, 6)) for e in m.joints if e.mode == 'rotate' and e.rotation}})
