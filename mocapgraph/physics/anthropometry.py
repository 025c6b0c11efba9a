"""Segment masses, centres of mass and radii of gyration after de Leva (1996), mapped onto bones.

de Leva, "Adjustments to Zatsiorsky-Seluyanov's segment inertia parameters", J. Biomech. 29(9),
1996, Table 4 (male): mass as a fraction of body mass, centre of mass as a fraction of the segment
length from its proximal end, radii of gyration (sagittal, transverse, longitudinal) as fractions of
the segment length. Capsule radii are not in de Leva: they are our choice, fractions of standing
height, noted per row.

A character's bones are classified by joint names (Kinect, BVH and Mixamo spellings); segments of
one class share its mass in proportion to their lengths (the pelvis's three bones share the lower
trunk; the two sides share twice a limb row); a bone of no known class is ``other`` and gets mass from its capsule volume at 1000 kg/m^3.
Masses are then scaled so the character weighs ``body_mass``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..retarget.character import Character


@dataclass(frozen=True)
class SegmentClass:
    """One row of de Leva's table with our capsule radius."""

    mass_frac: float        # of body mass
    com_frac: float         # from the proximal joint, of the bone length
    gyration: tuple[float, float, float]  # sagittal, transverse, longitudinal; of the bone length
    radius_frac: float      # capsule radius, of standing height (our choice)


DE_LEVA: dict[str, SegmentClass] = {
    # head + neck: de Leva's head CoM sits 40 % of vertex-C7 above C7; on our neck-to-head-centre
    # bone that is 0.65 of the way.
    "head": SegmentClass(0.0694, 0.65, (0.362, 0.376, 0.312), 0.055),
    "upper_trunk": SegmentClass(0.1596, 0.5, (0.716, 0.454, 0.659), 0.045),
    "middle_trunk": SegmentClass(0.1633, 0.5, (0.482, 0.383, 0.468), 0.075),
    "lower_trunk": SegmentClass(0.1117, 0.5, (0.615, 0.551, 0.587), 0.060),
    "upper_arm": SegmentClass(0.0271, 0.5772, (0.285, 0.269, 0.158), 0.026),
    "forearm": SegmentClass(0.0162, 0.4574, (0.276, 0.265, 0.121), 0.021),
    "hand": SegmentClass(0.0061, 0.79, (0.628, 0.513, 0.401), 0.020),
    "thigh": SegmentClass(0.1416, 0.4095, (0.329, 0.329, 0.149), 0.040),
    "shank": SegmentClass(0.0433, 0.4459, (0.255, 0.249, 0.103), 0.029),
    "foot": SegmentClass(0.0137, 0.4415, (0.257, 0.245, 0.124), 0.014),
    "other": SegmentClass(0.0, 0.5, (0.3, 0.3, 0.15), 0.02),
}


LIMBS = ("upper_arm", "forearm", "hand", "thigh", "shank", "foot")


def classify_bone(character: Character, child: int) -> str:
    """De Leva class of the bone from ``parents[child]`` to ``child`` (by joint names)."""
    p = int(character.parents[child])
    pn = character.joint_names[p].lower().replace("mixamorig:", "")
    cn = character.joint_names[child].lower().replace("mixamorig:", "")
    if "head" in cn or "neck" in cn:
        return "head"
    if character.parents[p] < 0 or any(k in pn for k in ("pelvis", "hipcenter", "spinebase")):
        return "lower_trunk"
    if "elbow" in pn or "forearm" in pn:
        return "forearm"
    if "wrist" in pn or ("hand" in pn and "hand" in cn):
        return "hand"
    if "knee" in pn or "leg" == pn[-3:] and "up" not in pn:
        return "shank"
    if "ankle" in pn or "foot" in pn:
        return "foot"
    if ("shoulder" in pn or "arm" in pn) and "center" not in pn and "spine" not in pn:
        return "upper_arm"
    if ("hip" in pn or "upleg" in pn or "thigh" in pn) and "center" not in pn:
        return "thigh"
    lateral = any(k in cn for k in ("left", "right")) or cn[-2:] in ("_l", "_r")
    if lateral and any(k in cn for k in ("shoulder", "clavicle", "collar")):
        return "upper_trunk"
    if any(k in pn for k in ("spine", "chest", "torso", "abdomen", "back")):
        return "middle_trunk"
    return "other"


@dataclass(frozen=True)
class BoneMass:
    """Per bone (indexed by its child joint): class, mass kg, capsule radius m, CoM fraction,
    radii of gyration in metres (perpendicular, perpendicular, along the bone)."""

    classes: tuple[str, ...]
    mass: np.ndarray       # [J] kg; 0 for the root (no bone)
    radius: np.ndarray     # [J] m
    com_frac: np.ndarray   # [J]
    gyration: np.ndarray   # [J, 3] m


def bone_masses(character: Character, body_mass: float, height: float | None = None) -> BoneMass:
    """Mass, radius and inertia data of every bone of ``character`` for a ``body_mass`` kg person.

    ``height``: standing height for the radii (m); default the character's rest height above its
    lowest joint plus a head allowance of 7 %.
    """
    if not np.isfinite(body_mass) or body_mass <= 0:
        raise ValueError(f"body_mass: {body_mass} kg is not a positive mass")
    n = character.n_joints
    pos, _ = character.rest_pose()
    if height is None:
        height = float((pos[:, 2].max() - pos[:, 2].min()) * 1.07) or 1.75
    lengths = np.nan_to_num(character.bone_lengths, nan=0.0)
    classes = ["" if character.parents[j] < 0 else classify_bone(character, j) for j in range(n)]
    radius = np.array([0.0 if not c else DE_LEVA[c].radius_frac * height for c in classes])
    mass = np.zeros(n)
    for cls in set(classes) - {"", "other"}:
        idx = [j for j in range(n) if classes[j] == cls]
        # a limb row is one side's segment; several bones of one side (a BVH's split forearm)
        # share it by length, as the trunk rows' pieces do
        sides = 2 if cls in LIMBS else 1
        share = lengths[idx] / max(lengths[idx].sum(), 1e-9) * min(sides, len(idx))
        mass[idx] = DE_LEVA[cls].mass_frac * body_mass * share
    other = [j for j in range(n) if classes[j] == "other"]
    if other:
        r, L = radius[other], lengths[other]
        mass[other] = 1000.0 * (np.pi * r ** 2 * L + 4.0 / 3.0 * np.pi * r ** 3)
    mass *= body_mass / mass.sum()
    com = np.array([0.5 if not c else DE_LEVA[c].com_frac for c in classes])
    gyr = np.array([(0.3, 0.3, 0.15) if not c else DE_LEVA[c].gyration for c in classes])
    # perpendicular axes: the mean of sagittal and transverse (a capsule is axisymmetric)
    perp = gyr[:, :2].mean(axis=1)
    gyration = np.stack([perp, perp, gyr[:, 2]], axis=1) * lengths[:, None]
    return BoneMass(tuple(classes), mass, radius, com, gyration)
