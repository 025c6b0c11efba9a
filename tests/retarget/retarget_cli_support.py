"""Helpers of the retarget CLI tests."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from mocapgraph.formats.bvh_file import bvh_to_skeleton, read_bvh
from mocapgraph.retarget.source import skeleton_source


@lru_cache(maxsize=4)
def cmu_source(path: str):
    """The source a BVH file is, as the batch command and the node read it."""
    motion = read_bvh(path)
    tr = bvh_to_skeleton(motion)
    rest = motion.rest_positions()
    p = tr.parents
    offs = np.where((p >= 0)[:, None], rest - rest[np.maximum(p, 0)], rest)
    return skeleton_source(tr.names, p, offs, has_orientations=True, kind_hint="bvh")
