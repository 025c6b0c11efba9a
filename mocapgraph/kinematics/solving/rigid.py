"""Batched weighted rigid fits (Kabsch / SVD) of marker clusters, many limbs and frames at once.

A limb's pose is the rotation R and translation t that best map its reference (base-pose)
marker positions onto the current ones: ``x_cur ~= R @ x_ref + t`` (column vectors, metres,
world frame). This is Kiip section 3.3.1 (Charalambous / Kwon SVD method with the reflection
fix), done on centroid-removed coordinates with per-marker weights so that occluded (NaN)
markers simply get weight 0.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MIN_MARKERS = 3
# Relative size of the second singular value below which the visible markers are (nearly)
# collinear and the rotation about their line is undetermined.
_COLLINEAR_TOL = 1e-6


@dataclass(frozen=True)
class RigidFit:
    """Result of :func:`fit_rigid` over leading batch dims ``B`` (e.g. ``[T, L]``).

    rotation: float[B,3,3], maps reference -> current (NaN where invalid).
    translation: float[B,3] m, ``x_cur = rotation @ x_ref + translation`` (NaN where invalid).
    centroid: float[B,3] m, weighted centroid of the visible current markers.
    ref_centroid: float[B,3] m, weighted centroid of the same markers in the reference.
    rms: float[B] m, weighted RMS distance of the visible markers after the fit (NaN if invalid).
    n_visible: int64[B], markers that took part in the fit.
    valid: bool[B], at least three visible, non-collinear markers.
    """

    rotation: np.ndarray
    translation: np.ndarray
    centroid: np.ndarray
    ref_centroid: np.ndarray
    rms: np.ndarray
    n_visible: np.ndarray
    valid: np.ndarray


def fit_rigid(
    ref: np.ndarray,
    cur: np.ndarray,
    weights: np.ndarray | None = None,
    min_markers: int = MIN_MARKERS,
) -> RigidFit:
    """Weighted Kabsch fit of ``ref`` onto ``cur`` for every batch entry at once.

    ref: float[..., K, 3] reference positions (broadcast against ``cur``), NaN = unusable.
    cur: float[..., K, 3] current positions, NaN = not visible.
    weights: optional float[..., K] >= 0 (broadcast); padding slots should carry weight 0.
    Batch entries with fewer than ``min_markers`` usable markers (or collinear ones) come back
    NaN with ``valid`` False; nothing raises for missing data.
    """
    ref = np.asarray(ref, dtype=float)
    cur = np.asarray(cur, dtype=float)
    vis = np.isfinite(cur).all(-1) & np.isfinite(ref).all(-1)
    w = vis.astype(float) if weights is None else np.where(vis, weights, 0.0)
    w = np.broadcast_to(w, np.broadcast_shapes(w.shape, vis.shape))
    n_vis = np.count_nonzero(w > 0, axis=-1)
    wsum = w.sum(-1)
    safe = np.where(wsum > 0, wsum, 1.0)[..., None]
    wk = w[..., None]
    ref0 = np.where(wk > 0, ref, 0.0)
    cur0 = np.where(wk > 0, cur, 0.0)
    c_ref = (wk * ref0).sum(-2) / safe
    c_cur = (wk * cur0).sum(-2) / safe
    a = ref0 - c_ref[..., None, :]
    b = cur0 - c_cur[..., None, :]
    h = np.swapaxes(a * wk, -1, -2) @ b  # [...,3,3] = sum_k w a b^T
    u, s, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    d = np.sign(_det3(v) * _det3(u))
    d = np.where(d == 0, 1.0, d)
    v[..., :, 2] *= d[..., None]
    rot = v @ np.swapaxes(u, -1, -2)
    resid = b - a @ np.swapaxes(rot, -1, -2)
    rms = np.sqrt((w * (resid * resid).sum(-1)).sum(-1) / safe[..., 0])
    valid = (n_vis >= min_markers) & (s[..., 1] > _COLLINEAR_TOL * s[..., 0]) & (s[..., 0] > 0)
    trans = c_cur - (rot @ c_ref[..., None])[..., 0]
    nan3 = ~valid[..., None]
    rot = np.where(nan3[..., None], np.nan, rot)
    trans = np.where(nan3, np.nan, trans)
    rms = np.where(valid, rms, np.nan)
    c_cur = np.where(n_vis[..., None] > 0, c_cur, np.nan)
    c_ref = np.where(n_vis[..., None] > 0, c_ref, np.nan)
    return RigidFit(rot, trans, c_cur, c_ref, rms, n_vis, valid)


def _det3(a: np.ndarray) -> np.ndarray:
    """Determinants of stacked 3x3 matrices (elementwise; much faster than LAPACK for many small ones)."""
    return (a[..., 0, 0] * (a[..., 1, 1] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 1])
            - a[..., 0, 1] * (a[..., 1, 0] * a[..., 2, 2] - a[..., 1, 2] * a[..., 2, 0])
            + a[..., 0, 2] * (a[..., 1, 0] * a[..., 2, 1] - a[..., 1, 1] * a[..., 2, 0]))


def gather_limb_markers(markers: np.ndarray, limb_index: np.ndarray) -> np.ndarray:
    """Markers per limb: float[..., M, 3] with int[L, K] indices (-1 = padding) -> [..., L, K, 3].

    Padding slots come back NaN so that :func:`fit_rigid` ignores them.
    """
    idx = np.asarray(limb_index)
    out = np.asarray(markers, dtype=float)[..., np.where(idx >= 0, idx, 0), :]
    return np.where((idx >= 0)[..., None], out, np.nan)
