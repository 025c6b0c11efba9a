"""Quality codes of messages whose type may not carry them (older versions, computed poses)."""
from __future__ import annotations

import numpy as np

from .types import QUALITY_GOOD, QUALITY_MISSING, CharacterPose


def character_quality(msg: CharacterPose) -> np.ndarray:
    """int64[J] quality of a character pose: its ``joint_quality`` where the type has one (v2),
    else good for every finite joint; missing wherever the position is not finite."""
    finite = np.isfinite(msg.joint_positions).all(-1)
    q = getattr(msg, "joint_quality", None)
    if q is not None and len(q) == len(finite):
        return np.where(finite, np.asarray(q, np.int64), QUALITY_MISSING)
    return np.where(finite, QUALITY_GOOD, QUALITY_MISSING).astype(np.int64)
