"""Parametric human body for the synthetic actor: segments, joint centres and joint DOFs.

Frames and units: metres, world Z up, X forward, Y to the actor's left. The base pose is a T-pose
(arms along +-Y, palms down, legs straight, feet forward) in which every limb's orientation is the
identity, so every rotation below is "relative to the base pose".

Segment lengths are fractions of standing height after Drillis & Contini (as tabulated in Winter,
"Biomechanics and Motor Control of Human Movement", fig. 4.1): shoulder 0.818 H, hip 0.530 H,
knee 0.285 H, ankle 0.039 H, upper arm 0.186 H, forearm 0.146 H, hand 0.108 H, foot 0.152 H.

A joint's local rotation (child relative to parent, base-pose frame) is
``Q = R(a2, t2) @ R(a1, t1) @ R(a0, t0)``: DOF 0 (flexion) first, then DOF 1 (ab/adduction,
lateral bend, deviation), then DOF 2 (axial twist). Axes are signed per side so that positive
angles are flexion / abduction / internal rotation on both sides. Hinge joints use DOF 0 only.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

# Canonical segments in tree order; parent index, proximal joint name, side (+1 left, -1 right, 0).
SEGMENTS: tuple[tuple[str, int, str | None, int], ...] = (
    ("pelvis", -1, None, 0),
    ("thorax", 0, "waist", 0),
    ("head", 1, "neck", 0),
    ("clavicle_l", 1, "sternoclavicular_l", 1),
    ("upper_arm_l", 3, "shoulder_l", 1),
    ("forearm_l", 4, "elbow_l", 1),
    ("hand_l", 5, "wrist_l", 1),
    ("clavicle_r", 1, "sternoclavicular_r", -1),
    ("upper_arm_r", 7, "shoulder_r", -1),
    ("forearm_r", 8, "elbow_r", -1),
    ("hand_r", 9, "wrist_r", -1),
    ("thigh_l", 0, "hip_l", 1),
    ("shank_l", 11, "knee_l", 1),
    ("foot_l", 12, "ankle_l", 1),
    ("thigh_r", 0, "hip_r", -1),
    ("shank_r", 14, "knee_r", -1),
    ("foot_r", 15, "ankle_r", -1),
)
SEGMENT_NAMES = tuple(s[0] for s in SEGMENTS)
SEGMENT_PARENT = np.array([s[1] for s in SEGMENTS], dtype=np.int64)
SEGMENT_SIDE = np.array([s[3] for s in SEGMENTS], dtype=np.int64)
# Canonical joint k is the proximal joint of segment k + 1.
CANON_JOINTS = tuple(s[2] for s in SEGMENTS[1:])

# Joint kind -> DOFs (name, unsigned axis (x, y, z) with side factors, gym range deg lo, hi, major).
# Axis entries: numbers, or "s" / "-s" for the side sign (+1 left, -1 right).
_DOF_TABLE: dict[str, tuple[tuple[str, tuple, float, float, bool], ...]] = {
    "waist": (("flexion", (0, 1, 0), -30, 50, True), ("lateral_bend", (1, 0, 0), -40, 40, True),
              ("twist", (0, 0, 1), -45, 45, True)),
    "neck": (("flexion", (0, 1, 0), -50, 50, True), ("lateral_bend", (1, 0, 0), -45, 45, True),
             ("twist", (0, 0, 1), -60, 60, True)),
    "sternoclavicular": (("elevation", ("s", 0, 0), -10, 30, False), ("protraction", (0, 0, "-s"), -25, 25, False),
                         ("twist", (0, "s", 0), -15, 15, False)),
    "shoulder": (("flexion", (0, 0, "-s"), -45, 90, True), ("abduction", ("s", 0, 0), -60, 60, True),
                 ("twist", (0, "s", 0), -60, 60, True)),
    "elbow": (("flexion", (0, 0, "-s"), 0, 120, True),),
    "wrist": (("flexion", ("-s", 0, 0), -60, 60, True), ("deviation", (0, 0, "-s"), -30, 30, True),
              ("twist", (0, "s", 0), -45, 45, True)),
    "hip": (("flexion", (0, -1, 0), -30, 90, True), ("abduction", ("s", 0, 0), -30, 45, True),
            ("twist", (0, 0, "-s"), -40, 40, True)),
    "knee": (("flexion", (0, 1, 0), 0, 120, True),),
    "ankle": (("dorsiflexion", (0, -1, 0), -45, 30, True), ("inversion", ("-s", 0, 0), -25, 30, True),
              ("twist", (0, 0, "-s"), -25, 25, True)),
}


def joint_kind(joint: str) -> str:
    return joint[:-2] if joint.endswith(("_l", "_r")) else joint


@dataclass(frozen=True)
class Dof:
    name: str
    axis: np.ndarray  # unit vector, base-pose frame
    lo_deg: float
    hi_deg: float
    major: bool


def joint_dofs(joint: str) -> tuple[Dof, ...]:
    """DOFs of a canonical joint with side-signed unit axes in the base-pose frame."""
    side = -1.0 if joint.endswith("_r") else 1.0
    out = []
    for name, ax, lo, hi, major in _DOF_TABLE[joint_kind(joint)]:
        v = np.array([side if a == "s" else -side if a == "-s" else float(a) for a in ax])
        out.append(Dof(name, v / np.linalg.norm(v), lo, hi, major))
    return tuple(out)


@dataclass(frozen=True)
class BodyParams:
    """Anthropometry as fractions of standing height (metres)."""

    height: float = 1.75
    hip_z: float = 0.530          # hip joint centre height
    hip_half_width: float = 0.049  # half the inter-hip-centre distance
    knee_z: float = 0.285
    ankle_z: float = 0.039
    waist_z: float = 0.580        # lumbosacral joint
    waist_x: float = -0.020
    neck_z: float = 0.830         # C7/T1
    neck_x: float = -0.020
    head_top_z: float = 1.000
    shoulder_z: float = 0.800     # glenohumeral centre
    shoulder_half_width: float = 0.110
    sc_z: float = 0.810
    sc_x: float = 0.030
    sc_half_width: float = 0.012
    upper_arm: float = 0.186
    forearm: float = 0.146
    hand: float = 0.108
    foot_length: float = 0.152
    heel_back: float = 0.030

    def scaled(self, jitter: float, rng: np.random.Generator) -> "BodyParams":
        """Copy with every ratio multiplied by 1 + U(-jitter, jitter) (height kept)."""
        kw = {k: v * (1.0 + rng.uniform(-jitter, jitter)) for k, v in self.__dict__.items() if k != "height"}
        return replace(self, **kw)


@dataclass(frozen=True)
class BodyGeometry:
    """Base-pose geometry: per segment proximal point, distal point, marker radius range (m)."""

    params: BodyParams
    proximal: np.ndarray   # [S,3] proximal joint centre (pelvis: hip midpoint)
    distal: np.ndarray     # [S,3] distal end (child joint centre or segment tip)
    radius: np.ndarray     # [S,2] min/max marker distance from the segment axis
    feet_z: float = field(default=0.0)


def build_geometry(params: BodyParams) -> BodyGeometry:
    """Joint centres of the T-pose for ``params`` (metres, world frame, feet on z = 0)."""
    h = params.height
    p = params
    prox = np.zeros((len(SEGMENTS), 3))
    dist = np.zeros((len(SEGMENTS), 3))
    rad = np.zeros((len(SEGMENTS), 2))
    idx = {n: i for i, n in enumerate(SEGMENT_NAMES)}

    def put(name, a, b, r):
        prox[idx[name]] = np.asarray(a, float) * h
        dist[idx[name]] = np.asarray(b, float) * h
        rad[idx[name]] = r

    put("pelvis", (0, 0, p.hip_z), (p.waist_x, 0, p.waist_z), (0.10, 0.13))
    put("thorax", (p.waist_x, 0, p.waist_z), (p.neck_x, 0, p.neck_z), (0.10, 0.14))
    put("head", (p.neck_x, 0, p.neck_z), (0.01, 0, p.head_top_z), (0.07, 0.09))
    for s, sg in (("l", 1), ("r", -1)):
        sh = (0, sg * p.shoulder_half_width, p.shoulder_z)
        el = (0, sg * (p.shoulder_half_width + p.upper_arm), p.shoulder_z)
        wr = (0, sg * (p.shoulder_half_width + p.upper_arm + p.forearm), p.shoulder_z)
        tip = (0, sg * (p.shoulder_half_width + p.upper_arm + p.forearm + p.hand), p.shoulder_z)
        put(f"clavicle_{s}", (p.sc_x, sg * p.sc_half_width, p.sc_z), sh, (0.03, 0.06))
        put(f"upper_arm_{s}", sh, el, (0.05, 0.08))
        put(f"forearm_{s}", el, wr, (0.04, 0.07))
        put(f"hand_{s}", wr, tip, (0.03, 0.05))
        hip = (0, sg * p.hip_half_width, p.hip_z)
        kn = (0, sg * p.hip_half_width, p.knee_z)
        an = (0, sg * p.hip_half_width, p.ankle_z)
        toe = (p.foot_length - p.heel_back, sg * (p.hip_half_width + 0.006), 0.006)
        put(f"thigh_{s}", hip, kn, (0.06, 0.10))
        put(f"shank_{s}", kn, an, (0.05, 0.08))
        put(f"foot_{s}", an, toe, (0.03, 0.06))
    return BodyGeometry(params, prox, dist, rad)


# Layout limb names -> canonical segment kind (side from l/r markers in the name).
_KIND_ALIASES = {
    "pelvis": "pelvis", "lower_torso": "pelvis", "hips": "pelvis", "sacrum": "pelvis", "root": "pelvis",
    "thorax": "thorax", "upper_torso": "thorax", "chest": "thorax", "trunk": "thorax", "torso": "thorax",
    "spine": "thorax",
    "head": "head", "skull": "head",
    "clavicle": "clavicle", "collar": "clavicle", "shoulder_girdle": "clavicle",
    "upper_arm": "upper_arm", "humerus": "upper_arm", "uparm": "upper_arm", "arm": "upper_arm",
    "lower_arm": "forearm", "forearm": "forearm", "radius": "forearm",
    "hand": "hand",
    "upper_leg": "thigh", "thigh": "thigh", "femur": "thigh",
    "lower_leg": "shank", "shank": "shank", "tibia": "shank", "calf": "shank", "leg": "shank",
    "foot": "foot",
}


def segment_for_limb(limb: str) -> str | None:
    """Canonical segment for a layout limb name (``upper_leg_l`` -> ``thigh_l``), or None."""
    n = limb.strip().lower().replace("-", "_").replace(" ", "_")
    side = None
    for pre, sd in (("left_", "l"), ("right_", "r"), ("l_", "l"), ("r_", "r")):
        if n.startswith(pre):
            n, side = n[len(pre):], sd
            break
    for suf, sd in (("_left", "l"), ("_right", "r"), ("_l", "l"), ("_r", "r")):
        if side is None and n.endswith(suf):
            n, side = n[: -len(suf)], sd
            break
    kind = _KIND_ALIASES.get(n)
    if kind is None:
        return None
    if kind in ("pelvis", "thorax", "head"):
        return kind if side is None else None
    return f"{kind}_{side}" if side else None
