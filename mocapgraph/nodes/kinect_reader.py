"""Kinect body-tracking replay node: a Kinect v2 (25 joints) or v1 (20 joints) CSV as live
SkeletonPose frames, at the recording's own time stamps (dropped frames stay gaps)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from ..bus import Param
from ..formats import SkeletonTrial, read_kinect_csv
from .skeleton_source import SkeletonFilePlayer
from .source_base import SourceError


class KinectReader(SkeletonFilePlayer):
    """Replays a Kinect body CSV as ``skeleton_pose`` + latched ``skeleton_info``.

    Camera space becomes the world frame with the person facing +X, Z up (origin at the sensor,
    or on the floor with ``ground: feet``; a ``device`` file can then place the sensor in the
    room). Tracking state per joint: 2 tracked, 1 inferred (position kept), 0 not tracked
    (position NaN); samples behind the sensor (camera z < 0) are not tracked, and their number
    is ``behind_sensor`` in the reader status. Frames are sent at their recorded time stamps,
    so dropped frames stay gaps.
    ``rest_offsets`` in skeleton_info are observed (median bone length along the mean bone
    direction; the root: its median position): a Kinect stream has no rest pose.
    """

    summary = "replay a Kinect v2 (25 joints) / v1 (20 joints) body-tracking CSV as SkeletonPose"
    ground = Param("sensor", "origin of the world Z: 'sensor' keeps the sensor at Z = 0, 'feet' puts the "
                             "floor (estimated from the feet) at Z = 0", choices=("sensor", "feet"))
    version = Param("auto", "expected Kinect version: 'v2' (25 joints), 'v1' (20 joints) or 'auto'",
                    choices=("auto", "v1", "v2"))

    def read_trial(self, path: Path) -> SkeletonTrial:
        trial = read_kinect_csv(path, ground=self.ground)
        found = f"v{trial.extra.get('kinect_version', 2)}"
        if self.version != "auto" and self.version != found:
            raise SourceError(f"{path.name}: is a Kinect {found} recording ({trial.n_joints} joints), "
                              f"the graph expects {self.version}")
        return trial

    def status_data(self) -> dict[str, Any]:
        d = super().status_data()
        d["behind_sensor"] = int(self.trial.extra.get("behind_sensor", 0)) if hasattr(self, "trial") else 0
        return d

    def source_kind(self, trial: SkeletonTrial) -> str:
        return f"kinect_v{trial.extra.get('kinect_version', 2)}"
