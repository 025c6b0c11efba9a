"""An input capture file as frames, by its extension: one reader for every command and converter.

BVH, Kinect CSV and a video (one camera's markerless pose) -> :class:`SkeletonTrial` (time stamps from 0 at the first frame, its rest
offsets from :func:`skeleton_rest_offsets`); C3D and TRC -> :class:`MarkerTrial`. Metres, world
frame (Z up), as each format's reader gives. Bags (.mcap) are read by ``bag.sources``, a layer up.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..kinematics.rest_offsets import observed_rest_offsets, offsets_from_rest
from .errors import FormatError
from .marker_trial import MarkerTrial
from .skeleton_trial import SkeletonTrial

#: extension -> kind of the files a skeleton or marker reader takes
SKELETON_KINDS = {".bvh": "bvh", ".csv": "kinect_csv", ".txt": "kinect_csv",
                  # one camera's markerless pose (mocapgraph.video, the 'video' extra)
                  ".mp4": "video", ".avi": "video", ".mov": "video", ".mkv": "video", ".webm": "video"}
MARKER_KINDS = {".c3d": "c3d", ".trc": "trc"}
FILE_KINDS = {**MARKER_KINDS, **SKELETON_KINDS}


def file_kind(path: str | Path) -> str | None:
    """The kind of a capture file by its extension ("bvh", "kinect_csv", "c3d", "trc"), None if unknown."""
    return FILE_KINDS.get(Path(path).suffix.lower())


def read_skeleton_file(path: str | Path, *, ground: str = "sensor") -> SkeletonTrial:
    """A BVH or Kinect CSV as a SkeletonTrial stamped from 0 ns at its first frame.

    A BVH keeps its rest pose (``extra["rest_positions"]``, [J, 3] m world). ground: a Kinect
    CSV's Z origin ("sensor" or "feet", see read_kinect_csv). FormatError for another kind.
    """
    kind = SKELETON_KINDS.get(Path(path).suffix.lower())
    if kind == "bvh":
        from .bvh_file import bvh_to_skeleton, read_bvh
        motion = read_bvh(path)
        trial = bvh_to_skeleton(motion, start_ns=0)
        trial.extra["rest_positions"] = motion.rest_positions()
        return trial
    if kind == "kinect_csv":
        from .kinect_csv import read_kinect_csv
        trial = read_kinect_csv(path, ground=ground)
        # the sensor's own clock is kept apart from the stream's time: stamps from the first frame
        trial.timestamps_ns = trial.timestamps_ns - (trial.timestamps_ns[0] if trial.n_frames else 0)
        return trial
    if kind == "video":
        from ..video.capture import video_trial
        from ..video.frames import VideoUnavailable
        try:
            trial, _ = video_trial(path, ground="feet")
        except VideoUnavailable as exc:
            raise FormatError(path, str(exc)) from None
        trial.timestamps_ns = trial.timestamps_ns - (trial.timestamps_ns[0] if trial.n_frames else 0)
        return trial
    raise FormatError(path, f"not a skeleton file ({Path(path).suffix or 'no extension'}; expected "
                            f"{', '.join(sorted(SKELETON_KINDS))})")


def skeleton_rest_offsets(trial: SkeletonTrial, *, tracked_only: bool = False) -> np.ndarray:
    """[J, 3] offsets from each joint's parent (roots: their rest position), m, world: the BVH
    rest pose when the trial has one, else ``observed_rest_offsets`` over its frames (with
    tracked_only, over the samples of tracking state 2 only)."""
    rest = trial.extra.get("rest_positions")
    if rest is not None:
        return offsets_from_rest(rest, trial.parents)
    P = trial.positions
    if tracked_only:
        P = np.where((trial.tracking_state == 2)[..., None], P, np.nan)
    return observed_rest_offsets(P, trial.parents)


def read_marker_file(path: str | Path, *, up_axis: str | None = None) -> MarkerTrial:
    """A C3D or TRC as a MarkerTrial; up_axis: the file's up axis (None/"auto": what it says)."""
    kind = MARKER_KINDS.get(Path(path).suffix.lower())
    if kind == "c3d":
        from .c3d_file import read_c3d
        return read_c3d(path, up_axis=up_axis)
    if kind == "trc":
        from .trc_file import read_trc
        return read_trc(path, up_axis=up_axis)
    raise FormatError(path, f"unknown marker file type {Path(path).suffix or '(no extension)'!r} "
                            "(expected .c3d or .trc)")
