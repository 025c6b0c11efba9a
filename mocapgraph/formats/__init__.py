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
Devices: :mod:`mocapgraph.formats.wire_protocol` (text and binary marker frames),
:mod:`mocapgraph.formats.natnet` (OptiTrack NatNet 3.0-4.2 packets; Motive axes, decoded as sent).

The names above are imported from their module on first use (PEP 562 ``__getattr__``): every
``mocapgraph.formats.X`` import runs this file first, and loading every format here would cost a
node that reads one format scipy's import (BVH, C3D segments) and a third of a second.
"""
from __future__ import annotations

from importlib import import_module
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import FormatError

if TYPE_CHECKING:
    from .bvh_file import BvhMotion, bvh_to_skeleton, read_bvh, write_bvh
    from .c3d_file import read_c3d, write_c3d
    from .c3d_segments import c3d_segment_count, read_c3d_segments
    from .kinect_csv import (KINECT_V1_JOINTS, KINECT_V1_PARENTS, KINECT_V2_JOINTS,
                             KINECT_V2_PARENTS, read_kinect_csv)
    from .marker_trial import MarkerTrial
    from .skeleton_trial import SkeletonTrial
    from .trc_file import read_trc, write_trc

# Public name -> the submodule defining it (a test checks this table against the modules).
_LAZY: dict[str, str] = {
    "BvhMotion": "bvh_file", "bvh_to_skeleton": "bvh_file", "read_bvh": "bvh_file", "write_bvh": "bvh_file",
    "read_c3d": "c3d_file", "write_c3d": "c3d_file",
    "c3d_segment_count": "c3d_segments", "read_c3d_segments": "c3d_segments",
    "KINECT_V1_JOINTS": "kinect_csv", "KINECT_V1_PARENTS": "kinect_csv", "KINECT_V2_JOINTS": "kinect_csv",
    "KINECT_V2_PARENTS": "kinect_csv", "read_kinect_csv": "kinect_csv",
    "MarkerTrial": "marker_trial", "SkeletonTrial": "skeleton_trial",
    "read_trc": "trc_file", "write_trc": "trc_file",
}


def __getattr__(name: str) -> Any:
    """A public name of `_LAZY`, imported from its module on first use (then a plain attribute)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


def read_markers(path: str | Path, **options) -> MarkerTrial:
    """Read a marker file by its extension (.c3d or .trc); options go to that reader."""
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        from .c3d_file import read_c3d
        return read_c3d(path, **options)
    if suffix == ".trc":
        from .trc_file import read_trc
        return read_trc(path, **options)
    raise FormatError(path, f"unknown marker file type {suffix or '(no extension)'!r} "
                            f"(expected .c3d or .trc)")


def write_markers(path: str | Path, trial: MarkerTrial, **options) -> None:
    """Write a marker file by its extension (.c3d or .trc)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".c3d":
        from .c3d_file import write_c3d
        return write_c3d(path, trial, **options)
    if suffix == ".trc":
        from .trc_file import write_trc
        return write_trc(path, trial, **options)
    raise FormatError(path, f"unknown marker file type {suffix or '(no extension)'!r}")


__all__ = ["BvhMotion", "FormatError", "KINECT_V1_JOINTS", "KINECT_V1_PARENTS",
           "KINECT_V2_JOINTS", "KINECT_V2_PARENTS", "MarkerTrial", "SkeletonTrial",
           "bvh_to_skeleton", "c3d_segment_count", "read_bvh", "read_c3d", "read_c3d_segments",
           "read_kinect_csv", "read_markers",
           "read_trc", "write_bvh", "write_c3d", "write_markers", "write_trc"]
