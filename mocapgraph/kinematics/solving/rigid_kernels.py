"""Compiled kernel of one frame's weighted rigid fits of every limb's marker cluster.

The same fit as :func:`mocapgraph.kinematics.solving.rigid.fit_rigid` (its numpy code is the reference
the tests compare this to): per limb the weighted centroids, the covariance ``h = sum w a b^T``
of the centred reference and current markers, the proper rotation with ``b ~ R a`` (here from
the leading eigenvector of Horn's 1987 quaternion matrix of h, which is Kabsch's rotation with
the reflection fix wherever the fit is valid), the translation, the weighted RMS, and validity
(at least ``min_markers`` seen, second singular value of h over 1e-6 of the first). Float64 /
int64 arrays (metres, world frame) grouped in tuples, outputs preallocated by the caller.
"""
from __future__ import annotations

import numpy as np

from mocapgraph.jit import kernel_calling, readonly

from .. import quat_kernels

kernel = kernel_calling(quat_kernels)   # its eigen-solve (quat_kernels.jacobi_eigen)

_COLLINEAR_TOL = 1e-6   # as rigid._COLLINEAR_TOL


@kernel
def _usable(markers: np.ndarray, m: int, ref: np.ndarray, l: int, k: int, w: float) -> bool:
    """Marker m (seen) counts for slot k of limb l (its reference point known, its weight > 0)."""
    return (w > 0.0 and np.isfinite(markers[m, 0]) and np.isfinite(markers[m, 1]) and np.isfinite(markers[m, 2])
            and np.isfinite(ref[l, k, 0]) and np.isfinite(ref[l, k, 1]) and np.isfinite(ref[l, k, 2]))


# The kernels take their arrays grouped in plain tuples (limbs, out, scratch below): numba's
# dispatcher types a plain tuple in C, a named tuple in Python (~0.5 us more per field, a call).


@kernel
def fit_frame(markers: np.ndarray, limbs: tuple, out: tuple, scratch: tuple) -> None:
    """Fit every limb of one frame: markers float[M,3] (NaN = unseen).

    limbs = (ref[L,K,3] base-pose markers (m, NaN = unusable), idx0[L,K] marker indices (padding
    any index, weight 0), weights[L,K], min_markers): the constants (`limbs_of`);
    out = (rot[L,3,3], trans[L,3] (``x = R x_ref + t``, m), rms[L] (m), nvis[L], valid[L] (0/1))
    is written, invalid limbs getting NaN rot, trans and rms; scratch = `scratch()`."""
    ref, idx0, weights, min_markers = limbs
    rot, trans, rms, nvis, valid = out
    h, N, V, M3 = scratch
    L, K = idx0.shape
    for l in range(L):
        n = 0
        ws = 0.0
        cr0 = cr1 = cr2 = cc0 = cc1 = cc2 = 0.0
        for k in range(K):
            m = idx0[l, k]
            w = weights[l, k]
            if not _usable(markers, m, ref, l, k, w):
                continue
            n += 1
            ws += w
            cr0 += w * ref[l, k, 0]
            cr1 += w * ref[l, k, 1]
            cr2 += w * ref[l, k, 2]
            cc0 += w * markers[m, 0]
            cc1 += w * markers[m, 1]
            cc2 += w * markers[m, 2]
        nvis[l] = n
        safe = ws if ws > 0.0 else 1.0
        cr0, cr1, cr2, cc0, cc1, cc2 = cr0 / safe, cr1 / safe, cr2 / safe, cc0 / safe, cc1 / safe, cc2 / safe
        h[:] = 0.0
        for k in range(K):
            m = idx0[l, k]
            w = weights[l, k]
            if not _usable(markers, m, ref, l, k, w):
                continue
            a0, a1, a2 = ref[l, k, 0] - cr0, ref[l, k, 1] - cr1, ref[l, k, 2] - cr2
            b0, b1, b2 = markers[m, 0] - cc0, markers[m, 1] - cc1, markers[m, 2] - cc2
            h[0, 0] += w * a0 * b0
            h[0, 1] += w * a0 * b1
            h[0, 2] += w * a0 * b2
            h[1, 0] += w * a1 * b0
            h[1, 1] += w * a1 * b1
            h[1, 2] += w * a1 * b2
            h[2, 0] += w * a2 * b0
            h[2, 1] += w * a2 * b1
            h[2, 2] += w * a2 * b2
        if not _spread_ok(h, M3, V, n, min_markers):
            valid[l] = 0
            for i in range(3):
                trans[l, i] = np.nan
                for j in range(3):
                    rot[l, i, j] = np.nan
            rms[l] = np.nan
            continue
        valid[l] = 1
        R = rot[l]
        _horn_rotation(h, N, V, R)
        trans[l, 0] = cc0 - (R[0, 0] * cr0 + R[0, 1] * cr1 + R[0, 2] * cr2)
        trans[l, 1] = cc1 - (R[1, 0] * cr0 + R[1, 1] * cr1 + R[1, 2] * cr2)
        trans[l, 2] = cc2 - (R[2, 0] * cr0 + R[2, 1] * cr1 + R[2, 2] * cr2)
        ss = 0.0
        for k in range(K):
            m = idx0[l, k]
            w = weights[l, k]
            if not _usable(markers, m, ref, l, k, w):
                continue
            a0, a1, a2 = ref[l, k, 0] - cr0, ref[l, k, 1] - cr1, ref[l, k, 2] - cr2
            for i in range(3):
                r = markers[m, i] - (R[i, 0] * a0 + R[i, 1] * a1 + R[i, 2] * a2) - (cc0 if i == 0 else (cc1 if i == 1 else cc2))
                ss += w * r * r
        rms[l] = np.sqrt(ss / safe)


@kernel
def _spread_ok(h: np.ndarray, M3: np.ndarray, V: np.ndarray, n: int, min_markers: int) -> bool:
    """A valid fit: at least ``min_markers`` seen, and h's second singular value over 1e-6 of its
    first (from the eigenvalues of h^T h; collinear markers fix no rotation)."""
    for i in range(3):
        for j in range(3):
            M3[i, j] = h[0, i] * h[0, j] + h[1, i] * h[1, j] + h[2, i] * h[2, j]
    quat_kernels.jacobi_eigen(M3, V, False)
    e0, e1, e2 = M3[0, 0], M3[1, 1], M3[2, 2]
    big = max(e0, e1, e2)
    small = min(e0, e1, e2)
    mid = e0 + e1 + e2 - big - small
    s0 = np.sqrt(big) if big > 0.0 else 0.0
    s1 = np.sqrt(mid) if mid > 0.0 else 0.0
    return n >= min_markers and s0 > 0.0 and s1 > _COLLINEAR_TOL * s0


@kernel
def _horn_rotation(h: np.ndarray, N: np.ndarray, V: np.ndarray, R: np.ndarray) -> None:
    """R[3,3] with ``b ~ R a`` from the leading eigenvector of Horn's matrix N(h) (as global_track._HORN)."""
    trh = h[0, 0] + h[1, 1] + h[2, 2]
    N[0, 0] = trh
    N[0, 1] = N[1, 0] = h[1, 2] - h[2, 1]
    N[0, 2] = N[2, 0] = h[2, 0] - h[0, 2]
    N[0, 3] = N[3, 0] = h[0, 1] - h[1, 0]
    for i in range(3):
        for j in range(3):
            N[1 + i, 1 + j] = h[i, j] + h[j, i] - (trh if i == j else 0.0)
    quat_kernels.jacobi_eigen(N, V, True)
    best = 0
    for i in range(1, 4):
        if N[i, i] > N[best, best]:
            best = i
    qw, qx, qy, qz = V[0, best], V[1, best], V[2, best], V[3, best]
    qn = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    qw, qx, qy, qz = qw / qn, qx / qn, qy / qn, qz / qn
    R[0, 0] = 1.0 - 2.0 * (qy * qy + qz * qz)
    R[0, 1] = 2.0 * (qx * qy - qw * qz)
    R[0, 2] = 2.0 * (qx * qz + qw * qy)
    R[1, 0] = 2.0 * (qx * qy + qw * qz)
    R[1, 1] = 1.0 - 2.0 * (qx * qx + qz * qz)
    R[1, 2] = 2.0 * (qy * qz - qw * qx)
    R[2, 0] = 2.0 * (qx * qz - qw * qy)
    R[2, 1] = 2.0 * (qy * qz + qw * qx)
    R[2, 2] = 1.0 - 2.0 * (qx * qx + qy * qy)


def warm() -> None:
    """Compile the kernel once: one limb of three markers."""
    ref = np.array([[[0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.05]]])
    L = 1
    limbs = limbs_of(ref, np.array([[0, 1, 2]]), np.ones((1, 3)), 3)
    for markers in (ref[0] + 1.0, readonly(ref[0] + 1.0)):   # a node's markers are decoded, read-only
        out = (np.zeros((L, 3, 3)), np.zeros((L, 3)), np.zeros(L), np.zeros(L, dtype=np.int64),
               np.zeros(L, dtype=np.int64))
        fit_frame(markers, limbs, out, scratch())


def limbs_of(ref: np.ndarray, idx0: np.ndarray, weights: np.ndarray, min_markers: int) -> tuple:
    """`fit_frame`'s limbs tuple, as contiguous float64 / int64 arrays."""
    return (np.ascontiguousarray(ref, dtype=float), np.ascontiguousarray(idx0, dtype=np.int64),
            np.ascontiguousarray(weights, dtype=float), int(min_markers))


def scratch() -> tuple:
    """`fit_frame`'s work arrays: (h [3,3] covariance, N [4,4] Horn's matrix, V [4,4] eigenvectors, M3 [3,3])."""
    return np.zeros((3, 3)), np.zeros((4, 4)), np.zeros((4, 4)), np.zeros((3, 3))
