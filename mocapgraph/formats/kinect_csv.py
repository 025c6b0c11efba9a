"""Kinect body-tracking CSV (one line per frame) -> :class:`SkeletonTrial`.

Line layout (comma separated, a trailing comma is allowed)::

    ticks, x0, y0, z0, state0, x1, y1, z1, state1, ...   (25 joints: Kinect v2, 20: v1)

``ticks`` is the sensor time stamp in 100 ns units; x, y, z are metres in Kinect camera space;
state is 0 not tracked, 1 inferred, 2 tracked. Joint order is the SDK's JointType order
(:data:`KINECT_V2_JOINTS` / :data:`KINECT_V1_JOINTS`).

Kinect camera space (Kinect for Windows SDK 2.0, "Coordinate mapping"): origin at the depth
sensor, right-handed, Y up, Z out of the sensor toward the user, X toward the sensor's own
left (so a user facing the sensor has their left shoulder at negative X). The reader
converts to the world frame with the tracked person facing +X (toward the sensor), Z up and
Y to the person's left: (x, y, z)_world = (-z, -x, y)_camera, a proper rotation; the origin
stays at the sensor (``ground="feet"`` moves Z = 0 to the floor estimated from the feet).
Positions of not-tracked joints (state 0) become NaN; inferred ones are kept and flagged.
A sample with camera z < 0 lies behind the sensor, which the depth camera cannot see: whatever
state the file gives it, it is made not tracked (state 0, NaN) and counted in
``trial.extra["behind_sensor"]`` and a note. So is z == 0 with a state other than 0 (on the
sensor itself; 0, 0, 0 with state 0 is how the SDK writes an untracked joint, not a fault).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .axes import describe_rotation, to_world_rotation
from .errors import FormatError
from .skeleton_trial import NOT_TRACKED, SkeletonTrial

KINECT_V2_JOINTS: tuple[str, ...] = (
    "SpineBase", "SpineMid", "Neck", "Head",
    "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
    "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight",
    "SpineShoulder", "HandTipLeft", "ThumbLeft", "HandTipRight", "ThumbRight",
)
# Bones of the Kinect v2 SDK (thumbs hang from the wrists, hand tips from the hands).
KINECT_V2_PARENTS: tuple[int, ...] = (
    -1, 0, 20, 2,
    20, 4, 5, 6,
    20, 8, 9, 10,
    0, 12, 13, 14,
    0, 16, 17, 18,
    1, 7, 6, 11, 10,
)
KINECT_V1_JOINTS: tuple[str, ...] = (
    "HipCenter", "Spine", "ShoulderCenter", "Head",
    "ShoulderLeft", "ElbowLeft", "WristLeft", "HandLeft",
    "ShoulderRight", "ElbowRight", "WristRight", "HandRight",
    "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
    "HipRight", "KneeRight", "AnkleRight", "FootRight",
)
KINECT_V1_PARENTS: tuple[int, ...] = (
    -1, 0, 1, 2,
    2, 4, 5, 6,
    2, 8, 9, 10,
    0, 12, 13, 14,
    0, 16, 17, 18,
)
# world = CAMERA_TO_WORLD @ camera: person faces +X (camera -Z), up is camera +Y
CAMERA_TO_WORLD = to_world_rotation("+Y", "-Z")
TICK_NS = 100


def read_kinect_csv(path: str | Path, *, ground: str = "sensor") -> SkeletonTrial:
    """Read a Kinect v1/v2 body CSV (see module doc) into a world-frame SkeletonTrial.

    ground: "sensor" keeps the origin at the sensor; "feet" shifts Z so the 5th percentile
    of tracked foot/ankle heights is 0 (a floor estimate, stated in conversions).
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as e:
        raise FormatError(path, f"cannot read file ({e.strerror or e})") from None
    notes: list[str] = []
    rows = [ln.strip().rstrip(",") for ln in lines if ln.strip()]
    if rows and not rows[0].split(",")[0].strip().lstrip("-").isdigit():
        notes.append("skipped a header line")
        rows = rows[1:]
    if not rows:
        raise FormatError(path, "Kinect CSV holds no frames")
    n_fields = len(rows[0].split(","))
    n_joints = (n_fields - 1) // 4
    if (n_fields - 1) % 4 or n_joints not in (20, 25):
        raise FormatError(path, f"Kinect CSV line 1 has {n_fields} fields; expected 1 + 4 x 25 "
                                f"(v2) or 1 + 4 x 20 (v1)")
    names, parents = ((KINECT_V2_JOINTS, KINECT_V2_PARENTS) if n_joints == 25
                      else (KINECT_V1_JOINTS, KINECT_V1_PARENTS))
    bad = [k + 1 for k, r in enumerate(rows) if r.count(",") != n_fields - 1]
    if bad:
        raise FormatError(path, f"Kinect CSV line {bad[0]} has {rows[bad[0] - 1].count(',') + 1} "
                                f"fields, not {n_fields}")
    try:
        ticks = np.array([int(r.split(",", 1)[0]) for r in rows], dtype=np.int64)
        data = np.array(",".join(r.split(",", 1)[1] for r in rows).split(","),
                        dtype=np.float64).reshape(len(rows), n_joints, 4)
    except ValueError as e:
        raise FormatError(path, f"Kinect CSV holds a non-numeric field ({e})") from None
    cam = data[..., :3]
    state = data[..., 3]
    if np.any((state != 0) & (state != 1) & (state != 2)):
        raise FormatError(path, "Kinect CSV tracking state outside 0/1/2")
    state = state.astype(np.int8)
    behind = (cam[..., 2] <= 0) & (state != NOT_TRACKED)  # impossible for a depth camera
    n_behind = int(behind.sum())
    if n_behind:
        state[behind] = NOT_TRACKED
        t_bad = np.flatnonzero(behind.any(axis=1))
        notes.append(f"{n_behind} joint samples lie behind the sensor (camera z <= 0) in "
                     f"{t_bad.size} frames (first on data line {t_bad[0] + 1}); marked not tracked")
    ts = ticks * TICK_NS
    if np.any(np.diff(ts) <= 0):
        notes.append("time stamps are not strictly increasing")
    dts = np.diff(ts)
    dts = dts[dts > 0]
    rate = 1e9 / float(np.median(dts)) if dts.size else 30.0
    if dts.size:
        dropped = int(np.sum(np.round(dts / np.median(dts)) - 1))
        if dropped > 0:
            notes.append(f"about {dropped} dropped frames (gaps in the time stamps)")

    pos = np.einsum("ij,tkj->tki", CAMERA_TO_WORLD, cam)
    pos[state == NOT_TRACKED] = np.nan
    conversions = [f"Kinect camera space -> world, person facing +X "
                   f"({describe_rotation(CAMERA_TO_WORLD)}); origin at the sensor",
                   "time stamps 100 ns ticks -> ns",
                   "not-tracked joints -> NaN"]
    if ground == "feet":
        feet = [names.index(n) for n in names if n.startswith(("Foot", "Ankle"))]
        z = pos[:, feet, 2]
        z = z[~np.isnan(z)]
        if z.size:
            floor = float(np.percentile(z, 5))
            pos[..., 2] -= floor
            conversions.append(f"Z shifted by {-floor:+.3f} m to put the floor (from the feet) "
                               f"at Z = 0")
    elif ground != "sensor":
        raise ValueError("ground must be 'sensor' or 'feet'")
    return SkeletonTrial(names=list(names), parents=np.array(parents), positions=pos,
                         tracking_state=state, timestamps_ns=ts, rate_hz=rate,
                         source=str(path), conversions=conversions, notes=notes,
                         extra={"kinect_version": 2 if n_joints == 25 else 1,
                                "behind_sensor": n_behind})
