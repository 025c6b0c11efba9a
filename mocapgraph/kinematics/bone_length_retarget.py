"""Shum & Ho's bone-length retargeting (section 7, Eq 3-4): joint positions onto a character's bone lengths.

For a joint i with parent j, the source bone direction d = (P_i - P_j) / |P_i - P_j| (Eq 3) and the
retargeted position P'_i = P'_j + d · L(i, j) (Eq 4), root first, one depth level of the hierarchy
at a time (vectorised over frames and over the joints of a level). The root keeps its source
position. Positions in metres, any frame (the result is in the same frame as the input).

Missing joints (NaN in, or a source bone shorter than ``min_bone_m`` so its direction is undefined):

* without ``fallback_directions`` the joint is left NaN, and so is every joint below it (their
  positions hang from it); the caller flags NaN output as missing;
* with ``fallback_directions`` ([J, 3] or [F, J, 3], e.g. the character's rest-pose bone directions
  in the same frame) the joint takes that direction, so the output is complete; with
  ``return_estimated`` the function also says which joints depend on a fallback (themselves or an
  ancestor), so that they are flagged estimated, never good.

A missing root stays NaN with its whole frame (no direction can place it).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np


@lru_cache(maxsize=64)
def _levels(parents: tuple[int, ...]) -> tuple[np.ndarray, ...]:
    """Joint indices per depth below the root(s); refuses cycles and unknown parents."""
    n = len(parents)
    depth = np.full(n, -1, dtype=np.int64)
    par = np.asarray(parents, dtype=np.int64)
    if ((par < -1) | (par >= n)).any():
        bad = int(np.flatnonzero((par < -1) | (par >= n))[0])
        raise ValueError(f"joint {bad}: parent index {par[bad]} is not a joint")
    depth[par < 0] = 0
    for d in range(n):  # at most n levels; each pass settles the next one
        frontier = (depth < 0) & (par >= 0)
        if not frontier.any():
            break
        ready = frontier & (depth[np.where(par >= 0, par, 0)] == d)
        depth[ready] = d + 1
    if (depth < 0).any():
        bad = int(np.flatnonzero(depth < 0)[0])
        raise ValueError(f"joint {bad}: its parents form a cycle")
    return tuple(np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1))


def retarget_bone_lengths(positions: np.ndarray, parents, lengths: np.ndarray, *,
                          fallback_directions: np.ndarray | None = None,
                          return_estimated: bool = False, min_bone_m: float = 1e-9):
    """Joint positions with the character's bone lengths, source bone directions kept (Eq 3-4).

    positions: [F, J, 3] or [J, 3] source joint positions, m (NaN = missing).
    parents: [J] parent index per joint, -1 for the root(s).
    lengths: [J] character bone length from each joint to its parent, m (the root's is ignored).
    fallback_directions: optional [J, 3] or [F, J, 3] unit bone directions for joints whose
    source direction is missing (see the module docstring).
    Returns positions of the input's shape, and with ``return_estimated`` also a bool mask of the
    same leading shape as the joints ([F, J] or [J]): True where the joint hangs from a fallback.
    """
    p = np.asarray(positions, dtype=np.float64)
    single = p.ndim == 2
    p = p.reshape(-1, p.shape[-2], 3)
    n = p.shape[1]
    par = tuple(int(x) for x in np.asarray(parents).reshape(-1))
    if len(par) != n:
        raise ValueError(f"{len(par)} parents for {n} joints")
    lengths = np.asarray(lengths, dtype=np.float64).reshape(-1)
    if lengths.shape[0] != n:
        raise ValueError(f"{lengths.shape[0]} bone lengths for {n} joints")
    levels = _levels(par)
    par_arr = np.asarray(par, dtype=np.int64)
    fb = None
    if fallback_directions is not None:
        fb = np.broadcast_to(np.asarray(fallback_directions, dtype=np.float64), p.shape)
        fb = fb / np.linalg.norm(fb, axis=-1, keepdims=True)
    out = np.full_like(p, np.nan)
    estimated = np.zeros(p.shape[:2], dtype=bool)
    out[:, levels[0]] = p[:, levels[0]]
    for level in levels[1:]:
        j = par_arr[level]
        bone = p[:, level] - p[:, j]                                 # Eq 3, before normalising
        norm = np.linalg.norm(bone, axis=-1, keepdims=True)
        ok = np.isfinite(norm) & (norm > min_bone_m)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = bone / norm
        if fb is not None:
            d = np.where(ok, d, fb[:, level])
            estimated[:, level] = ~ok[..., 0] | estimated[:, j]
        else:
            d = np.where(ok, d, np.nan)
        out[:, level] = out[:, j] + d * lengths[level][None, :, None]  # Eq 4
    if single:
        out, estimated = out[0], estimated[0]
    return (out, estimated) if return_estimated else out
