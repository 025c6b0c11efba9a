"""Calibration uncertainty: marker noise from the clusters' own residuals, standard errors of centres.

- :func:`marker_noise`: the marker noise (m, per coordinate) pooled from the rigid fits' residuals
  of every cluster of three or more markers against its mean shape (each fit leaves ``3K - 6``
  degrees of freedom).
- :func:`cluster_rotation_sd`: how well each cluster fixes its own orientation: the standard
  deviation (rad) of its fitted rotation about its worst axis under that noise,
  ``sigma / sqrt(lambda_min)`` of the cluster's inertia (a near-collinear cluster turns freely
  about its line; a two-marker one is infinite).
- :func:`score_covariance` / :func:`sphere_covariance`: the covariance of a least-squares centre
  from its own residuals (the sandwich ``N^-1 (sum_B s_B s_B^T) N^-1`` with the scores ``s`` summed
  over blocks of consecutive frames, so residuals correlated within a block still count once).
- :func:`hinge_axis_se`: a hinge axis's angular standard error by a block bootstrap over frames.

Everything is in metres and radians; the calibration turns them into millimetres for people.
"""
from __future__ import annotations

import numpy as np

#: consecutive frames whose scores are summed before their spread is taken
BLOCK_FRAMES = 10
#: bootstrap resamples for hinge axes
N_BOOTSTRAP = 64


def marker_noise(cur: np.ndarray, rotation: np.ndarray, translation: np.ndarray, valid: np.ndarray) -> tuple[float, float]:
    """Per-coordinate marker noise (m) of limb markers cur float[T,L,K,3] (NaN unseen) under their
    rigid fits (rotation [T,L,3,3], translation [T,L,3], valid [T,L]).

    Each frame's markers are carried back into the base pose (``R^T (x - t)``) and compared with
    their mean over the frames (not with the one base frame, whose own noise would count twice):
    ``sqrt(sum |dev|^2 / sum (3K - 6))`` over fits of K >= 3 markers (NaN when there are none),
    and the deviations' correlation from one frame to the next: near 0 for measurement noise,
    near 1 for skin moving over bone (slow, not noise: no correction for noise applies to it)."""
    y = np.einsum("tlji,tlkj->tlki", np.where(valid[..., None, None], rotation, 0.0),
                  cur - np.where(valid[..., None], translation, 0.0)[:, :, None, :])
    seen = np.isfinite(y).all(-1) & valid[..., None]                       # [T,L,K]
    k = seen.sum(-1)
    use = seen & (k >= 3)[..., None]
    cnt = use.sum(0)
    mean = np.where(use[..., None], y, 0.0).sum(0) / np.maximum(cnt, 1)[..., None]
    dev = np.where(use[..., None], y - mean, 0.0)
    dof = np.where(k >= 3, 3.0 * k - 6.0, 0.0).sum()
    if dof <= 0:
        return float("nan"), float("nan")
    both = use[1:] & use[:-1]
    num = np.where(both[..., None], dev[1:] * dev[:-1], 0.0).sum()
    den = np.where(both[..., None], dev[1:] ** 2, 0.0).sum()
    return float(np.sqrt((dev * dev).sum() / dof)), float(num / den) if den > 0 else float("nan")


def _cluster_inertia(ref: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float[L,3,3] m^2: each cluster's inertia about its centroid, int[L]: its markers) for
    markers ref float[L,K,3] (NaN padding) with weights [L,K] (a marker counts when weight > 0)."""
    has = (weight > 0) & np.isfinite(ref).all(-1)
    n = has.sum(1)
    a = np.where(has[..., None], ref, 0.0)
    c = a.sum(1) / np.maximum(n, 1)[:, None]
    d = np.where(has[..., None], a - c[:, None], 0.0)
    return (d * d).sum((1, 2))[:, None, None] * np.eye(3) - np.einsum("lki,lkj->lij", d, d), n


def cluster_rotation_cov(ref: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """float[L,3,3] rad^2: covariance of each cluster's fitted rotation (a small rotation vector
    in the base-pose frame), ``sigma^2 inertia^-1`` for markers ref float[L,K,3] with weights [L,K];
    zero for fewer than three markers (no own fit to correct)."""
    inertia, n = _cluster_inertia(ref, weight)
    ok = (n >= 3) & (np.linalg.eigvalsh(inertia)[:, 0] > 1e-12)
    inv = np.linalg.inv(np.where(ok[:, None, None], inertia, np.eye(3)))
    return np.where(ok[:, None, None], sigma * sigma * inv, 0.0)


def cluster_rotation_sd(ref: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """float[L] rad: standard deviation of each cluster's fitted rotation about its weakest axis,
    for markers ref float[L,K,3] (NaN padding) with weights [L,K] and noise sigma (m);
    inf for fewer than three markers."""
    inertia, n = _cluster_inertia(ref, weight)
    lam = np.linalg.eigvalsh(inertia)[:, 0]
    out = sigma / np.sqrt(np.maximum(lam, 1e-300))
    return np.where(n >= 3, out, np.inf)


def _block_sum(s: np.ndarray, block: int) -> np.ndarray:
    """Scores s [T,...] summed over blocks of ``block`` consecutive frames -> [B,...]."""
    T = s.shape[0]
    pad = (-T) % block
    if pad:
        s = np.concatenate([s, np.zeros((pad,) + s.shape[1:])])
    return s.reshape((-1, block) + s.shape[1:]).sum(1)


def _pinv_sym(nmat: np.ndarray, drop_first: np.ndarray | None = None, tol: float = 1e-9) -> np.ndarray:
    """Pseudo-inverse of symmetric [...,n,n] keeping eigenvalues above tol * the largest (and
    dropping the smallest direction where ``drop_first``: a hinge's undetermined axis)."""
    lam, vec = np.linalg.eigh(nmat)
    keep = lam > tol * np.maximum(lam[..., -1:], 1e-300)
    if drop_first is not None:
        keep[..., 0] &= ~drop_first
    inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    return np.einsum("...ik,...k,...jk->...ij", vec, inv, vec)


def score_covariance(a_mat: np.ndarray, w: np.ndarray, resid: np.ndarray, hinge: np.ndarray,
                     block: int = BLOCK_FRAMES) -> np.ndarray:
    """float[J,3,3]: covariance (m^2) of the SCoRE centre ``(x_a + x_b) / 2`` of each joint.

    a_mat [T,J,3,6] the system's rows, w [T,J] the robust weights, resid [T,J,3] = A x - b.
    A hinge's axis direction (undetermined by the motion) is left out: its covariance says how
    well the axis line is placed, not where along it the centre sits."""
    nmat = np.einsum("tjki,tj,tjkl->jil", a_mat, w, a_mat)
    score = np.einsum("tjki,tj,tjk->tji", a_mat, w, resid)                 # [T,J,6]
    sb = _block_sum(score, block)
    meat = np.einsum("bji,bjk->jik", sb, sb)
    ninv = _pinv_sym(nmat, np.asarray(hinge, dtype=bool))
    cov6 = ninv @ meat @ ninv
    h = 0.5 * np.hstack([np.eye(3), np.eye(3)])
    return h @ cov6 @ h.T


def sphere_covariance(g: np.ndarray, e: np.ndarray, frame: np.ndarray, keep_tol: float,
                      block: int = BLOCK_FRAMES) -> np.ndarray:
    """float[3,3]: covariance (m^2) of a linear sphere-fit centre from its rows g [N,3], residuals
    e [N] and each row's frame index [N] (rows of one frame are one observation)."""
    nmat = g.T @ g
    score = g * e[:, None]
    frames = np.unique(frame, return_inverse=True)[1]
    per_frame = np.zeros((frames.max(initial=-1) + 1, 3))
    np.add.at(per_frame, frames, score)
    sb = _block_sum(per_frame, block)
    ninv = _pinv_sym(nmat, tol=keep_tol)
    return ninv @ (sb.T @ sb) @ ninv


def hinge_axis_se(a_mat: np.ndarray, w: np.ndarray, rng: np.random.Generator,
                  block: int = BLOCK_FRAMES, n_boot: int = N_BOOTSTRAP) -> float:
    """Angular standard error (rad) of a SARA hinge axis (the smallest eigenvector of the normal
    matrix, ``u_a + u_b``) by a bootstrap over blocks of frames; a_mat [T,3,6], w [T]."""
    per = np.einsum("tki,t,tkl->til", a_mat, w, a_mat)
    nb = _block_sum(per, block)                                            # [B,6,6]
    axes = []
    for counts in rng.multinomial(nb.shape[0], np.full(nb.shape[0], 1.0 / nb.shape[0]), size=n_boot + 1):
        u = np.linalg.eigh(np.einsum("b,bij->ij", counts, nb))[1][:, 0]
        ax = u[:3] + u[3:]
        axes.append(ax / max(np.linalg.norm(ax), 1e-12))
    axes = np.array(axes)
    ref = np.linalg.eigh(nb.sum(0))[1][:, 0]
    ref = (ref[:3] + ref[3:]) / max(np.linalg.norm(ref[:3] + ref[3:]), 1e-12)
    ang = np.arccos(np.clip(np.abs(axes @ ref), 0.0, 1.0))
    return float(np.sqrt(np.mean(ang * ang)))


def standard_error(cov: np.ndarray) -> np.ndarray:
    """RMS 3-D error (m) of centres with covariances [...,3,3]: ``sqrt(trace)``."""
    return np.sqrt(np.maximum(np.trace(cov, axis1=-2, axis2=-1), 0.0))
