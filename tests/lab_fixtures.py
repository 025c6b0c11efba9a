"""Small capture files "from other labs", written by the tests themselves: C3D through ezc3d
(without screen parameters, with a header that disagrees with POINT:FRAMES, duplicate labels,
a ROTATION group), BVH and Kinect CSV as text. Every fixture knows its ground truth."""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

# a standing person seen from the side, metres, world Z up: head, pelvis, left/right foot
PERSON_LABELS = ("HEAD", "PELV", "LFOOT", "RFOOT")
PERSON_M = np.array([[0.05, 0.0, 1.70], [0.0, 0.0, 1.00], [0.10, 0.12, 0.05], [0.10, -0.12, 0.05]])
RATE = 100.0


def person_frames(n: int) -> np.ndarray:
    """[n, 4, 3] metres, world: the person walking forward (+X) at 1 m/s."""
    drift = np.zeros((n, 1, 3))
    drift[:, 0, 0] = np.arange(n) / RATE
    return PERSON_M[None] + drift


def write_points_c3d(path: Path, labels: list[str] | tuple[str, ...], points_m: np.ndarray, *,
                     y_screen: str | None = None, units: str = "mm", first_frame: int = 1,
                     rotations: np.ndarray | None = None, rotation_labels: list[str] | None = None) -> Path:
    """A float C3D written by ezc3d: ``points_m`` [T, M, 3] in file axes, metres (NaN = missing).

    y_screen None writes no X_SCREEN/Y_SCREEN at all ("" writes an empty one); rotations
    [T, S, 4, 4] (translations in metres) fill a ROTATION group.
    """
    import ezc3d

    scale = {"mm": 1000.0, "m": 1.0, "cm": 100.0}[units]
    T = points_m.shape[0]
    M = points_m.shape[1]
    c = ezc3d.c3d()
    c["parameters"]["POINT"]["RATE"]["value"] = [RATE]
    c["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    pts = np.ones((4, M, T))
    miss = np.isnan(points_m).any(axis=2)
    pts[:3] = np.where(miss[..., None], 0.0, points_m * scale).transpose(2, 1, 0)
    c["data"]["points"] = pts
    c["header"]["points"]["first_frame"] = first_frame - 1
    if M:
        c["data"]["meta_points"] = {"residuals": np.where(miss, -1.0, 0.5).T[None],
                                    "camera_masks": np.zeros((7, M, T), dtype=bool)}
    c.add_parameter("POINT", "UNITS", units)
    if y_screen is not None:
        c.add_parameter("POINT", "X_SCREEN", "+X" if y_screen else "")
        c.add_parameter("POINT", "Y_SCREEN", y_screen)
    if rotations is not None:
        r = rotations.copy()
        r[..., :3, 3] *= scale
        c["data"]["rotations"] = r.transpose(2, 3, 1, 0)  # [4, 4, S, T]
        c.add_parameter("ROTATION", "USED", rotations.shape[1])
        c.add_parameter("ROTATION", "LABELS", list(rotation_labels))
        c.add_parameter("ROTATION", "RATE", RATE)
    c.write(str(path))
    return path


def set_header_last_frame(path: Path, last: int) -> None:
    """Overwrite the header's last frame number (uint16, Intel files), leaving POINT:FRAMES."""
    raw = bytearray(path.read_bytes())
    raw[8:10] = struct.pack("<H", last)
    path.write_bytes(bytes(raw))


def cut_data(path: Path, keep_frames: int, n_points: int) -> None:
    """Cut the data block of a float, analog-free C3D after ``keep_frames`` frames."""
    raw = path.read_bytes()
    start = (struct.unpack("<H", raw[16:18])[0] - 1) * 512
    path.write_bytes(raw[:start + keep_frames * n_points * 16])


# ----- BVH --------------------------------------------------------------------------------------
def bvh_with_root_offset(path: Path, frames: int = 4, root_offset_y: float = 90.0) -> Path:
    """A BVH in centimetres whose root (Hips) has OFFSET 0 90 0 and absolute position channels
    holding the pelvis height 90 cm: legs of 45 + 40 + 5 cm put the feet on the floor."""
    lines = ["HIERARCHY", "ROOT Hips", "{", f"  OFFSET 0 {root_offset_y:g} 0",
             "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    for side, x in (("Left", 10.0), ("Right", -10.0)):
        rot = "CHANNELS 3 Zrotation Xrotation Yrotation"
        lines += [f"  JOINT {side}UpLeg", "  {", f"    OFFSET {x:g} 0 0", f"    {rot}",
                  f"    JOINT {side}Leg", "    {", "      OFFSET 0 -45 0", f"      {rot}",
                  f"      JOINT {side}Foot", "      {", "        OFFSET 0 -40 0",
                  "        CHANNELS 3 Zrotation Xrotation Yrotation",
                  "        End Site", "        {", "          OFFSET 0 -5 12", "        }",
                  "      }", "    }", "  }"]
    lines += ["  JOINT Head", "  {", "    OFFSET 0 75 0", "    CHANNELS 3 Zrotation Xrotation Yrotation",
              "    End Site", "    {", "      OFFSET 0 10 0", "    }", "  }", "}"]
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    for t in range(frames):
        # walking forward along BVH +Z, pelvis held at 90 cm: an absolute position
        lines.append(" ".join(["0", "90", f"{5.0 * t:g}"] + ["0"] * 3 + ["0"] * 3 * 7))
    path.write_text("\n".join(lines) + "\n")
    return path


# ----- Kinect -----------------------------------------------------------------------------------
def kinect_csv(path: Path, frames: int = 5, behind: tuple[tuple[int, int, int], ...] = (),
               z_behind: float = -0.4) -> Path:
    """A Kinect v2 CSV (25 joints, 30 Hz, the person 2 m in front of the sensor); ``behind`` lists
    (frame, joint, state) samples put behind the sensor (camera z = ``z_behind``)."""
    rng = np.random.default_rng(3)
    base = np.column_stack([rng.uniform(-0.3, 0.3, 25), rng.uniform(-0.9, 0.7, 25), np.full(25, 2.0)])
    rows = []
    for t in range(frames):
        xyz = base.copy()
        state = np.full(25, 2)
        for f, j, s in behind:
            if f == t:
                xyz[j, 2] = z_behind
                state[j] = s
        fields = [str(1_000_000 + t * 333_333)]
        for j in range(25):
            fields += [f"{xyz[j, 0]:.4f}", f"{xyz[j, 1]:.4f}", f"{xyz[j, 2]:.4f}", str(state[j])]
        rows.append(",".join(fields))
    path.write_text("\n".join(rows) + "\n")
    return path
