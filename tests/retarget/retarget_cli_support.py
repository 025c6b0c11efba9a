"""Helpers of the retarget CLI tests."""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from retarget_support import bvh_source


@lru_cache(maxsize=4)
def cmu_source(path: str):
    """The source a BVH file is, as the batch command and the node read it (``bvh_source``'s, cached)."""
    return bvh_source(Path(path))[2]
