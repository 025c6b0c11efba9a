"""What a retarget run is asked for and what it gives back: the options and the result arrays."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class RetargetOptions:
    """Each method on or off, and the foot-planting thresholds."""

    spread: bool = True            # spine/neck spread with end-point matching (Kiip 3.5.3)
    aim: bool = True               # clavicles aimed at the scaled shoulder (3.5.4)
    roll: bool = True              # roll joints share the twist (3.5.5)
    foot_planting: bool = False    # contact, planting and floor (3.5.6)
    root_scale: bool = True        # root translation times the leg-length ratio
    follow_bones: bool = True      # a rotate joint with one mapped child points its bone along the source bone
    scale: float | None = None     # fixed root ratio (None: the mapping's, else the leg ratio)
    floor_z: float = 0.0
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)   # world shift of the character, m (beside the performer)
    contact_height_m: float = 0.03
    contact_speed_mps: float = 0.3
    release_s: float = 0.15
    # a joint whose bone turned from the source bone by more than this beyond the rest-shape
    # difference is flagged estimated on that frame (bone_follow); None: never
    follow_tolerance_deg: float | None = 10.0


@dataclass
class RetargetResult:
    """[F, ...] arrays: local rotations wxyz (relative to rest), root and joint positions (m, world),
    joint quality (0 missing, 1 estimated, 2 good), foot contact per leg side (l, r)."""

    local_rotations: np.ndarray
    root_positions: np.ndarray
    joint_positions: np.ndarray
    joint_quality: np.ndarray
    contact: np.ndarray
