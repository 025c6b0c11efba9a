"""Anatomical roles of joint names in the common rigs (Kinect v1/v2, CMU, Mixamo, our optical actor).

A role names what a joint is on the body (``shoulder_l`` is the upper-arm joint whatever the rig
calls it: Kinect ``ShoulderLeft``, CMU ``LeftShoulder``, Mixamo ``LeftArm``). Automatic mappings pair
a character joint with the source joint of the same role; a rig not listed here pairs by identical
names. Roles of the optical actor also name the limb whose rotation drives the joint.
"""
from __future__ import annotations

_SIDES = (("l", "Left", "L"), ("r", "Right", "R"))

ROLES: dict[str, dict[str, str]] = {
    "kinect_v1": {"HipCenter": "pelvis", "Spine": "spine", "ShoulderCenter": "chest", "Head": "head"},
    "kinect_v2": {"SpineBase": "pelvis", "SpineMid": "spine", "SpineShoulder": "chest", "Neck": "neck",
                  "Head": "head"},
    "cmu": {"Hips": "pelvis", "lowerback": "spine", "Chest": "spine1", "Chest2": "chest", "lowerneck": "neck",
            "Neck": "neck1", "Head": "head"},
    "mixamo": {"Hips": "pelvis", "Spine": "spine", "Spine1": "spine1", "Spine2": "chest", "Neck": "neck",
               "Head": "head", "HeadTop_End": "head_end"},
    "optical": {"pelvis": "pelvis", "waist": "spine", "neck": "neck"},
}
for s, side, _ in _SIDES:
    ROLES["kinect_v1"].update({f"Shoulder{side}": f"shoulder_{s}", f"Elbow{side}": f"elbow_{s}",
                               f"Wrist{side}": f"wrist_{s}", f"Hand{side}": f"hand_{s}", f"Hip{side}": f"hip_{s}",
                               f"Knee{side}": f"knee_{s}", f"Ankle{side}": f"ankle_{s}", f"Foot{side}": f"toe_{s}"})
    ROLES["kinect_v2"].update({f"Shoulder{side}": f"shoulder_{s}", f"Elbow{side}": f"elbow_{s}",
                               f"Wrist{side}": f"wrist_{s}", f"Hand{side}": f"hand_{s}", f"Hip{side}": f"hip_{s}",
                               f"Knee{side}": f"knee_{s}", f"Ankle{side}": f"ankle_{s}", f"Foot{side}": f"toe_{s}",
                               f"HandTip{side}": f"hand_tip_{s}", f"Thumb{side}": f"thumb_{s}"})
    ROLES["cmu"].update({f"{side}Hip": f"hip_{s}", f"{side}Knee": f"knee_{s}", f"{side}Ankle": f"ankle_{s}",
                         f"{side}Toe": f"toe_{s}", f"{side}Collar": f"clavicle_{s}", f"{side}Shoulder": f"shoulder_{s}",
                         f"{side}Elbow": f"elbow_{s}", f"{side}Wrist": f"wrist_{s}", f"{s}hand": f"hand_{s}"})
    ROLES["mixamo"].update({f"{side}UpLeg": f"hip_{s}", f"{side}Leg": f"knee_{s}", f"{side}Foot": f"ankle_{s}",
                            f"{side}ToeBase": f"toe_{s}", f"{side}Shoulder": f"clavicle_{s}", f"{side}Arm": f"shoulder_{s}",
                            f"{side}ForeArm": f"elbow_{s}", f"{side}Hand": f"wrist_{s}"})
    ROLES["optical"].update({f"sternoclavicular_{s}": f"clavicle_{s}", f"shoulder_{s}": f"shoulder_{s}",
                             f"elbow_{s}": f"elbow_{s}", f"wrist_{s}": f"wrist_{s}", f"hip_{s}": f"hip_{s}",
                             f"knee_{s}": f"knee_{s}", f"ankle_{s}": f"ankle_{s}"})

# optical actor: the limb whose rotation drives the joint of each role (the bone leaving the joint)
OPTICAL_ROTATION_LIMB: dict[str, str] = {"pelvis": "lower_torso", "spine": "upper_torso", "chest": "upper_torso",
                                         "neck": "head", "head": "head"}
for s, _, _ in _SIDES:
    OPTICAL_ROTATION_LIMB.update({f"clavicle_{s}": f"clavicle_{s}", f"shoulder_{s}": f"upper_arm_{s}",
                                  f"elbow_{s}": f"lower_arm_{s}", f"wrist_{s}": f"hand_{s}",
                                  f"hand_{s}": f"hand_{s}", f"hip_{s}": f"upper_leg_{s}",
                                  f"knee_{s}": f"lower_leg_{s}", f"ankle_{s}": f"foot_{s}", f"toe_{s}": f"foot_{s}"})

# character joints that an automatic mapping aims (clavicles) rather than rotates
AIM_ROLES = {"clavicle_l", "clavicle_r"}
LEG_ROLES = {side: (f"hip_{side}", f"knee_{side}", f"ankle_{side}", f"toe_{side}") for side in ("l", "r")}


def roles_of(names) -> dict[str, str]:
    """{joint name: role} for the rig whose names these are (the table matching most names)."""
    names = list(names)
    best, hits = {}, 0
    for table in ROLES.values():
        n = sum(1 for x in names if x in table)
        if n > hits:
            best, hits = table, n
    return {x: best[x] for x in names if x in best}


def rig_of(names) -> str:
    """Which table of :data:`ROLES` fits these names best ('' for none)."""
    names = list(names)
    scores = {k: sum(1 for x in names if x in t) for k, t in ROLES.items()}
    k = max(scores, key=scores.get)
    return k if scores[k] else ""
