"""File formats and device wire protocols (pure: numpy/scipy, ezc3d and c3d for C3D).

Every reader returns data in the project's conventions (metres, world frame Z up X forward,
NaN for missing, ns time stamps, quaternions w x y z) and lists what it converted in
``.conversions``. Bad input raises :class:`FormatError`, whose message is one line naming
the file and the fault.

Markers: :func:`read_c3d`, :func:`write_c3d`, :func:`read_trc`, :func:`write_trc`,
:func:`read_markers` (by extension) -> :class:`MarkerTrial`.
Segment poses: :func:`read_c3d_segments` (a C3D's ROTATION group) -> :class:`SkeletonTrial`.
Skeletons: :func:`read_bvh` -> :class:`BvhMotion` (``forward_kinematics``), :func:`write_bvh`,
:func:`bvh_to_skeleton` and :func:`read_kinect_csv` -> :class:`SkeletonTrial`.
Devices: :mod:`mocapgraph.formats.wire_protocol` (text and binary marker frames).
"""
from __future__ import annotations

from pathlib import Path

from .bvh_file import BvhMotion, bvh_to_skeleton, read_bvh, write_bvh
from .c3d_file import read_c3d, write_c3d
from .c3d_segments import c3d_segment_count, read_c3d_segments
from .errors import FormatError
from .kinect_csv import (KINECT_V1_JOINTS, KINECT_V1_PARENTS, KINECT_V2_JOINTS,
                         KINECT_V2_PARENTS, read_kinect_csv)
from .marker_trial import MarkerTrial
from .skeleton_trial import SkeletonTrial
from .trc_file import read_trc, write_trc


def read_markers(path: str | Path, **options) -> MarkerTrial:
    """Read a marker file by its extension (.c3d or .trc); options go to that reader."""
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        return read_c3d(path, **options)
    if suffix == ".trc":
        return read_trc(path, **options)
    raise FormatError(path, f"unknown marker file type {suffix or '(no extension)'!r} "
                            f"(expected .c3d or .trc)")


def write_markers(path: str | Path, trial: MarkerTrial, **options) -> None:
    """Write a marker file by its extension (.c3d or .trc)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        return write_c3d(path, trial, **options)
    if suffix == ".trc":
        return write_trc(path, trial, **options)
    raise FormatError(path, f"unknown marker file type {suffix or '(no extension)'!r}")


__all__ = ["BvhMotion", "FormatError", "KINECT_V1_JOINTS", "KINECT_V1_PARENTS",
           "KINECT_V2_JOINTS", "KINECT_V2_PARENTS", "MarkerTrial", "SkeletonTrial",
           "bvh_to_skeleton", "c3d_segment_count", "read_bvh", "read_c3d", "read_c3d_segments",
           "read_kinect_csv", "read_markers",
           "read_trc", "write_bvh", "write_c3d", "write_markers", "write_trc"]
