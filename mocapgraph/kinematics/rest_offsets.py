"""Rest offsets of a skeleton: from its rest pose's positions, or observed over its frames (the one rule each).

``SkeletonInfo.rest_offsets`` and every source skeleton use them: each joint's offset from its
parent, m, in the frame of the positions (world, Z up); a root's offset is its rest position.
"""
from __future__ import annotations

import numpy as np


def offsets_from_rest(rest_positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """[J, 3] each joint's rest offset from its parent (a root: its rest position), m, from the rest
    pose's positions [J, 3] (a BVH's): the SkeletonInfo.rest_offsets of a file with a rest pose."""
    rest = np.asarray(rest_positions, dtype=np.float64)
    par = np.asarray(parents)
    return np.where((par >= 0)[:, None], rest - rest[np.maximum(par, 0)], rest)


def observed_rest_offsets(positions: np.ndarray, parents: np.ndarray) -> np.ndarray:
    """[J, 3] rest offsets, m, of a skeleton without a rest pose (Kinect, C3D segments), from its
    observed frames ``positions`` [T, J, 3] (NaN where a joint is not to be used), same frame.

    A bone: its median length over the frames that see both ends, laid along its mean observed
    direction (so the offset's length is exactly that median); a bone never seen: 0. A root: its
    median observed position (0 if never seen), as ``offsets_from_rest`` gives a root its rest position.
    """
    P = np.asarray(positions, dtype=np.float64)
    par = np.asarray(parents, dtype=np.int64)
    out = np.zeros((len(par), 3))
    root = np.flatnonzero(par < 0)
    seen_root = np.isfinite(P[:, root]).all(axis=2).any(axis=0) if len(P) else np.zeros(len(root), bool)
    if seen_root.any():
        # per-axis median of the frames where the root is seen (the median of a point cloud's axes)
        out[root[seen_root]] = np.nanmedian(P[:, root[seen_root]], axis=0)
    child = np.flatnonzero(par >= 0)
    if not child.size or not len(P):
        return out
    v = P[:, child] - P[:, par[child]]        # [T, C, 3]
    length = np.linalg.norm(v, axis=2)
    ok = np.isfinite(length) & (length > 1e-9)   # a zero-length bone has no direction to count
    unit = np.where(ok[..., None], v / np.where(ok, length, 1.0)[..., None], 0.0)
    direction = unit.sum(axis=0)
    norm = np.linalg.norm(direction, axis=1, keepdims=True)
    direction = np.divide(direction, norm, out=np.zeros_like(direction), where=norm > 0)
    seen = ok.any(axis=0)
    med = np.zeros(child.size)
    med[seen] = np.nanmedian(np.where(ok, length, np.nan)[:, seen], axis=0)
    out[child] = direction * med[:, None]
    return out
