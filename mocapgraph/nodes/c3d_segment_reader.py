"""C3D segment-pose replay node: a C3D's ROTATION group (Theia3D and other markerless systems)
as live SkeletonPose frames."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..bus import Param
from ..formats import SkeletonTrial, read_c3d_segments
from .marker_source import UP_AXIS_CHOICES
from .skeleton_source import SkeletonFilePlayer


class C3DSegmentReader(SkeletonFilePlayer):
    """Replays the segment poses of a C3D's ROTATION group as ``skeleton_pose`` + latched
    ``skeleton_info``.

    One joint per segment, named from ROTATION:LABELS: position = the segment origin (metres,
    world), orientation = the segment's own axes in the world (wxyz), tracking state 2, or 0 with
    NaN where the file marks the pose invalid. The file gives no hierarchy, so every segment is a
    root and ``rest_offsets`` are the segments' median world positions. Frames are numbered as
    the file does (C3D header frames) when the poses come at the point rate. Units and up axis
    as the c3d_reader (``up_axis`` 'auto' = POINT:Y_SCREEN, else Z). A file without a ROTATION
    group is reported in one line and the node exits with code 1.
    """

    summary = "replay a C3D's ROTATION group (segment poses: Theia3D, markerless) as SkeletonPose"
    up_axis = Param("auto", "the file's up axis, made world Z: 'auto' = POINT:Y_SCREEN, else Z; or x, y, z "
                            "with an optional sign", choices=UP_AXIS_CHOICES)

    def read_trial(self, path: Path) -> SkeletonTrial:
        return read_c3d_segments(path, up_axis=self.up_axis)

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "c3d_segments"

    def load(self, path: Path) -> None:
        super().load(path)
        if self.trial.n_frames and abs(self.rate_hz - self.trial.extra.get("point_rate", self.rate_hz)) < 1e-9:
            # same rate as the points: number frames as the file does (start_frame/end_frame)
            self.frame_numbers = int(self.trial.extra.get("first_frame", 1)) + np.arange(self.trial.n_frames)
