"""BVH playback node: any BVH hierarchy (any rotation order per joint) as a live skeleton source."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..bus import Param
from ..formats import SkeletonTrial, bvh_to_skeleton, read_bvh
from ..kinematics.rest_offsets import offsets_from_rest
from .skeleton_source import SkeletonFilePlayer


class BVHPlayer(SkeletonFilePlayer):
    """Plays a BVH file as ``skeleton_pose`` + latched ``skeleton_info``.

    Forward kinematics runs once for the whole file at load (vectorised); each frame is then a row
    lookup. BVH's Y-up axes become the world's Z up, X forward (the character faces +X); offsets
    become metres with ``scale`` (0 = guessed from the skeleton's height, e.g. CMU units or cm).
    Joint orientations are world rotations, identity in the BVH rest pose; ``rest_offsets`` are
    the BVH offsets in metres, world axes. Every joint is tracked (state 2).
    """

    summary = "play a BVH file (any hierarchy and rotation order: CMU, Mixamo...) as SkeletonPose"
    scale = Param(0.0, "metres per BVH unit; 0 = guess from the rest-pose height (CMU units, cm, inches, m)",
                  minimum=0.0)
    include_end_sites = Param(True, "also publish End Site joints (named <parent>_End)")

    def read_trial(self, path: Path) -> SkeletonTrial:
        self.motion = read_bvh(path, scale=self.scale or None)
        return bvh_to_skeleton(self.motion, include_end_sites=self.include_end_sites)

    def source_kind(self, trial: SkeletonTrial) -> str:
        return "bvh"

    def rest_offsets(self, trial: SkeletonTrial) -> np.ndarray:
        rest = self.motion.rest_positions()
        keep = [self.motion.names.index(n) for n in trial.names]
        return offsets_from_rest(rest[keep], trial.parents)
