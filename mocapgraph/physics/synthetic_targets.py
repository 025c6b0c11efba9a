"""Target poses of ``standard_20`` driven by the synthetic actor, with the actor's ground truth.

Both bodies stand in a T-pose with identity orientations at rest (Z up, X forward), so each
``standard_20`` joint takes the world rotation of the synthetic segment it starts (``JOINT_SEGMENT``)
and the character's forward kinematics gives a consistent target (positions and orientations);
the performer's own joint centres (segment ends of the synthetic body, ``JOINT_POINT``) are the
ground truth printed beside the target. Used by tests, benchmarks and the posture database's
synthetic clips; the live graph gets its targets from the retargeter instead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..retarget.character import Character, standard_20
from ..kinematics.quaternion import matrix_to_quat
from ..kinematics.synthetic.actor import SyntheticActor
from ..kinematics.synthetic.body import SEGMENT_NAMES

JOINT_SEGMENT = {
    "HipCenter": "pelvis", "Spine": "thorax", "ShoulderCenter": "thorax", "Head": "head",
    "ShoulderLeft": "upper_arm_l", "ElbowLeft": "forearm_l", "WristLeft": "hand_l", "HandLeft": "hand_l",
    "ShoulderRight": "upper_arm_r", "ElbowRight": "forearm_r", "WristRight": "hand_r", "HandRight": "hand_r",
    "HipLeft": "thigh_l", "KneeLeft": "shank_l", "AnkleLeft": "foot_l", "FootLeft": "foot_l",
    "HipRight": "thigh_r", "KneeRight": "shank_r", "AnkleRight": "foot_r", "FootRight": "foot_r",
}
# ground truth: (segment, where) with where 0 = proximal end, 1 = distal end, 0.5 = middle
JOINT_POINT = {
    "HipCenter": ("pelvis", 0.0), "Spine": ("thorax", 0.0), "ShoulderCenter": ("head", 0.0),
    "Head": ("head", 0.5), "ShoulderLeft": ("upper_arm_l", 0.0), "ElbowLeft": ("forearm_l", 0.0),
    "WristLeft": ("hand_l", 0.0), "HandLeft": ("hand_l", 0.5), "ShoulderRight": ("upper_arm_r", 0.0),
    "ElbowRight": ("forearm_r", 0.0), "WristRight": ("hand_r", 0.0), "HandRight": ("hand_r", 0.5),
    "HipLeft": ("thigh_l", 0.0), "KneeLeft": ("shank_l", 0.0), "AnkleLeft": ("foot_l", 0.0),
    "FootLeft": ("foot_l", 1.0), "HipRight": ("thigh_r", 0.0), "KneeRight": ("shank_r", 0.0),
    "AnkleRight": ("foot_r", 0.0), "FootRight": ("foot_r", 1.0),
}


@dataclass(frozen=True)
class TargetClip:
    """Frames of a target: local rotations [F, J, 4] wxyz, root [F, 3] m, positions [F, J, 3] m,
    world orientations [F, J, 4], the performer's joint centres [F, J, 3] m, times [F] s."""

    character: Character
    times: np.ndarray
    local_rotations: np.ndarray
    root: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray
    truth: np.ndarray

    def __len__(self) -> int:
        return len(self.times)


def synthetic_targets(start_s: float, stop_s: float, rate: float = 120.0, *, seed: int = 0,
                      character: Character | None = None, actor: SyntheticActor | None = None,
                      height: float = 1.75) -> TargetClip:
    """``standard_20`` (or a character with its joint names) following the synthetic performer
    over [start_s, stop_s) of its session (base 0-1 s, gym 1-17 s, walk 17-22, reach 22-25,
    turn 25-27.5, walk back 27.5-32.5, kick 32.5-35, turn back 35-37.5)."""
    from ..kinematics.synthetic.body import BodyParams
    ch = character or standard_20(height)
    actor = actor or SyntheticActor("kiip_full_body", rate=rate, seed=seed, body=BodyParams(height=height),
                                    duration_s=max(stop_s + 1.0, 38.0))
    frames = np.arange(int(round(start_s * rate)), int(round(stop_s * rate)))
    R, T = actor.pose(frames)
    seg = {n: i for i, n in enumerate(SEGMENT_NAMES)}
    names = ch.joint_names
    S = np.array([seg[JOINT_SEGMENT[n]] for n in names])
    W = R[:, S]                                          # world orientation per joint [F, J, 3, 3]
    par = ch.parents
    rest = ch._rest_matrices                             # rest · local = W[parent]^T W[j]
    Wp = np.where((par >= 0)[None, :, None, None], W[:, np.maximum(par, 0)], np.eye(3))
    rel = np.swapaxes(Wp, -1, -2) @ W
    local_m = np.swapaxes(rest, -1, -2)[None] @ rel
    local = matrix_to_quat(local_m)
    geo = actor.geometry
    truth = np.empty((len(frames), len(names), 3))
    for j, n in enumerate(names):
        s_name, w = JOINT_POINT[n]
        s = seg[s_name]
        x = (1 - w) * geo.proximal[s] + w * geo.distal[s]
        truth[:, j] = (R[:, s] @ x) + T[:, s]
    # The root goes where the character's mid-hip point meets the performer's (the hip joints are
    # defined the same in both bodies; the root joint is not: standard_20's sits behind the hips).
    rest_pos, _ = ch.rest_pose()
    r, pelvis = ch.root, seg[JOINT_SEGMENT[names[ch.root]]]
    hips = [names.index(h) for h in ("HipLeft", "HipRight")]
    mid_hip_in_pelvis = np.einsum("ij,i->j", R[0, pelvis], truth[0, hips].mean(axis=0) - T[0, pelvis])
    root_in_pelvis = mid_hip_in_pelvis - (rest_pos[hips].mean(axis=0) - rest_pos[r])
    root = (R[:, pelvis] @ root_in_pelvis) + T[:, pelvis]
    pos, orient = ch.forward_kinematics(local, root)
    return TargetClip(ch, frames / rate, local, root, pos, orient, truth)


SYNTHETIC_CLIPS = {"base": (0.0, 1.0), "gym": (1.0, 17.0), "walk": (17.0, 22.0), "reach": (22.0, 25.0),
                   "turn": (25.0, 27.5), "walk_back": (27.5, 32.5), "kick": (32.5, 35.0),
                   "turn_back": (35.0, 37.5)}


def synthetic_postures(spec: str, character: Character | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Positions [N, J, 3] and local rotations [N, J, 4] of ``synthetic:NAME[,NAME...][@SEED]``
    (clip names of :data:`SYNTHETIC_CLIPS` or ``START-STOP`` seconds); ValueError naming the fault."""
    body = spec.split(":", 1)[1] if spec.startswith("synthetic:") else spec
    seed = 0
    if "@" in body:
        body, s = body.rsplit("@", 1)
        try:
            seed = int(s)
        except ValueError:
            raise ValueError(f"{spec}: seed {s!r} is not an integer") from None
    pos, rot = [], []
    for part in filter(None, body.split(",")):
        if part in SYNTHETIC_CLIPS:
            a, b = SYNTHETIC_CLIPS[part]
        else:
            try:
                a, b = (float(x) for x in part.split("-"))
            except ValueError:
                raise ValueError(f"{spec}: {part!r} is neither a clip ({', '.join(SYNTHETIC_CLIPS)}) "
                                 "nor START-STOP seconds") from None
        try:
            clip = synthetic_targets(a, b, seed=seed, character=character)
        except KeyError as exc:
            raise ValueError(f"{spec}: the synthetic performer drives standard_20 joint names only ({exc})") from None
        pos.append(clip.positions)
        rot.append(clip.local_rotations)
    if not pos:
        raise ValueError(f"{spec}: no clip named")
    return np.concatenate(pos), np.concatenate(rot)
