"""What every skeleton source shares: ``skeleton_pose`` frames + latched ``skeleton_info``.

A skeleton source (Kinect CSV, BVH playback) turns a :class:`SkeletonTrial` into live
``SkeletonPose`` messages (positions m, world; orientations wxyz; tracking state per joint) and
publishes the joint definitions once, latched (``SkeletonInfo``: names, parents, rest offsets,
what was converted). An optional device configuration places the source in the room (sensor
height, yaw); it is applied to the whole file once, at load.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..bus import Output, Param
from ..formats import SkeletonTrial
from ..kinematics.rest_offsets import observed_rest_offsets
from ..messages import SkeletonInfo, SkeletonPose
from ..formats.device_file import DeviceConfig, device_or_default
from .source_base import FilePlayback, SourceError


class SkeletonFilePlayer(FilePlayback):
    """Replays a SkeletonTrial as ``skeleton_pose`` + latched ``skeleton_info``. Subclasses read
    the file (``read_trial``) and say what kind of source it is (``source_kind``)."""

    skeleton_pose = Output("skeleton_pose", SkeletonPose, "joint positions (m, world), orientations (wxyz, "
                           "world; NaN if the source has none) and tracking state, skeleton_info order")
    skeleton_info = Output("skeleton_info", SkeletonInfo, "latched joint names, parents, rest offsets "
                           "and conversions")
    source_id = Param("body0", "performer / body id carried in every SkeletonPose")
    device = Param("", "device configuration placing the source in the room (graph_configs/devices name "
                       "or path; its to_world is applied after the format's own conversion); '' = none")

    def read_trial(self, path: Path) -> SkeletonTrial:
        raise NotImplementedError

    def source_kind(self, trial: SkeletonTrial) -> str:
        raise NotImplementedError

    def rest_offsets(self, trial: SkeletonTrial) -> np.ndarray:
        """[J, 3] m, the file's frame: observed ones (a stream without a rest pose); a BVH overrides."""
        return observed_rest_offsets(trial.positions, trial.parents)

    def load(self, path: Path) -> None:
        trial = self.read_trial(path)
        if trial.n_frames == 0:
            raise SourceError(f"{path.name}: has no frames")
        dev: DeviceConfig = device_or_default(self.device)
        self.positions = np.ascontiguousarray(dev.points_to_world(trial.positions))
        J = trial.n_joints
        quats = trial.orientations if trial.orientations is not None else np.full((trial.n_frames, J, 4), np.nan)
        self.orientations = np.ascontiguousarray(dev.quats_to_world(quats))
        self.tracking = np.ascontiguousarray(trial.tracking_state)
        raw = self.rest_offsets(trial)
        rest = raw @ dev.rotation.T
        # a root's offset is its rest position: placed in the room like the positions, not only turned
        roots = trial.parents < 0
        rest[roots] = dev.points_to_world(raw[roots])
        notes = list(trial.conversions) + ([dev.describe()] if self.device else [])
        self.info = SkeletonInfo(source=self.source_kind(trial), joint_names=trial.names,
                                 joint_parent=trial.parents.astype(np.int32), rest_offsets=rest,
                                 units_note="; ".join(notes))
        self.times_ns = trial.timestamps_ns
        self.frame_numbers = np.arange(trial.n_frames)
        self.rate_hz = trial.rate_hz
        self.trial = trial
        for note in trial.notes:
            self.log.info("%s: %s", path.name, note)

    def announce(self) -> None:
        self.log.info("converted: %s", self.info.units_note)
        self.skeleton_info.publish(self.info)

    def emit(self, index: int, capture_ns: int) -> None:
        self.skeleton_pose.publish(SkeletonPose(
            source_id=self.source_id, frame_number=int(self.frame_numbers[index]),
            joint_positions=self.positions[index],
            joint_orientations=self.orientations[index], tracking_state=self.tracking[index]),
            capture_ns=capture_ns)

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["joints"] = len(self.info.joint_names) if hasattr(self, "info") else 0
        return d
