"""Compiled kernels of the live global fit: one tracked frame's Gauss-Newton iteration in one call.

The same problem, steps and stopping rule as :class:`mocapgraph.kinematics.solving.global_track.GlobalTracker`
(its numpy code is the reference the tests compare this to): per limb the rotation R and the
world position c of its base-pose marker centroid, stepped in the limb's own frame
(``c <- c - R v``, ``R <- R cay(-w)``). Residuals, weighted: markers ``R a + c - y``, joints
``R_a p_a + c_a - R_b p_b - c_b``, hinges ``R_a n - R_b n``. The normal matrix's diagonal
blocks are constant for a set of seen markers; its only off-diagonal blocks couple a limb to its
parent, so it is factored by block elimination from the leaves to the root (6x6 Cholesky per
limb, O(limbs)) instead of a dense 6L x 6L Cholesky; the factor made after a frame's first step
also serves the next frame's first step, as in the numpy tracker.

Arrays are float64 / int64, metres and radians, world frame Z up; outputs are preallocated by
the caller. The layout's constants and the tracker's state and scratch travel as two tuples laid
out as :class:`Layout` and :class:`Work` (plain tuples: numba types them in its C dispatcher, a
named tuple in Python). Point Jacobians in the limb frame are ``B = [-[p]x, m I]`` (3x6; m = 1 for points,
0 for hinge directions).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mocapgraph.jit import kernel, readonly

# Status codes of track_frame (>0 is the iteration count of a tracked frame).
UNFIXABLE, NOT_POSITIVE, NOT_CONVERGED, POOR_FIT = -1, -2, -3, -4


@kernel
def _add_btb(D: np.ndarray, p: np.ndarray, m: float, u: float) -> None:
    """D[6,6] += u B^T B for B = [-[p]x, m I]: [[|p|^2 I - p p^T, m [p]x], [-m [p]x, m^2 I]]."""
    pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
    for i in range(3):
        for j in range(3):
            D[i, j] += u * ((pp if i == j else 0.0) - p[i] * p[j])
    s = u * m
    # [p]x = [[0, -p2, p1], [p2, 0, -p0], [-p1, p0, 0]]
    D[0, 4] -= s * p[2]
    D[0, 5] += s * p[1]
    D[1, 3] += s * p[2]
    D[1, 5] -= s * p[0]
    D[2, 3] -= s * p[1]
    D[2, 4] += s * p[0]
    D[4, 0] -= s * p[2]
    D[5, 0] += s * p[1]
    D[3, 1] += s * p[2]
    D[5, 1] -= s * p[0]
    D[3, 2] -= s * p[1]
    D[4, 2] += s * p[0]
    for i in range(3, 6):
        D[i, i] += u * m * m


@kernel
def _add_coupling(C: np.ndarray, pa: np.ndarray, ma: float, Rrel: np.ndarray, pb: np.ndarray,
                  mb: float, w: float, T: np.ndarray) -> None:
    """C[6,6] -= w B_a^T Rrel B_b (T: 3x6 scratch)."""
    # T = Rrel B_b, B_b = [-[pb]x, mb I]; column j of -[pb]x is e_j x pb.
    for i in range(3):
        T[i, 0] = -(Rrel[i, 1] * pb[2] - Rrel[i, 2] * pb[1])
        T[i, 1] = -(Rrel[i, 2] * pb[0] - Rrel[i, 0] * pb[2])
        T[i, 2] = -(Rrel[i, 0] * pb[1] - Rrel[i, 1] * pb[0])
        for j in range(3):
            T[i, 3 + j] = mb * Rrel[i, j]
    # B_a^T = [[ [pa]x ], [ma I]]: rows 0-2 are pa x (column of T), rows 3-5 ma T.
    for j in range(6):
        t0, t1, t2 = T[0, j], T[1, j], T[2, j]
        C[0, j] -= w * (pa[1] * t2 - pa[2] * t1)
        C[1, j] -= w * (pa[2] * t0 - pa[0] * t2)
        C[2, j] -= w * (pa[0] * t1 - pa[1] * t0)
        C[3, j] -= w * ma * t0
        C[4, j] -= w * ma * t1
        C[5, j] -= w * ma * t2


@kernel
def _chol6(A: np.ndarray) -> bool:
    """In place lower Cholesky factor of the 6x6 A (upper part left as is); False if not positive."""
    for j in range(6):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        if not s > 0.0:
            return False
        d = np.sqrt(s)
        A[j, j] = d
        for i in range(j + 1, 6):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / d
    return True


@kernel
def _lower_solve(Lf: np.ndarray, b: np.ndarray) -> None:
    """b <- Lf^-1 b (Lf lower 6x6)."""
    for i in range(6):
        s = b[i]
        for k in range(i):
            s -= Lf[i, k] * b[k]
        b[i] = s / Lf[i, i]


@kernel
def _upper_solve(Lf: np.ndarray, b: np.ndarray) -> None:
    """b <- Lf^-T b (Lf lower 6x6)."""
    for i in range(5, -1, -1):
        s = b[i]
        for k in range(i + 1, 6):
            s -= Lf[k, i] * b[k]
        b[i] = s / Lf[i, i]


@kernel
def diagonal_blocks(seen: np.ndarray, lay: tuple, D: np.ndarray) -> None:
    """The normal matrix's diagonal blocks D[L,6,6] for this set of seen markers (seen int64[L,K]),
    with the numpy tracker's regularisation (1e-9 of the mean diagonal, plus 1e-12)."""
    idx0, pad, a, wm0, ja, jb, p_a, p_b, wj, hj, axis, wh, order, joint_of, parent, radius, table, rms_tol = lay
    L, K = seen.shape
    D[:] = 0.0
    for l in range(L):
        for k in range(K):
            if seen[l, k]:
                _add_btb(D[l], a[l, k], 1.0, wm0[l, k])
    for q in range(ja.size):
        _add_btb(D[ja[q]], p_a[q], 1.0, wj[q])
        _add_btb(D[jb[q]], p_b[q], 1.0, wj[q])
    for h in range(hj.size):
        _add_btb(D[ja[hj[h]]], axis[h], 0.0, wh[h])
        _add_btb(D[jb[hj[h]]], axis[h], 0.0, wh[h])
    tr = 0.0
    for l in range(L):
        for i in range(6):
            tr += D[l, i, i]
    reg = 1e-9 * tr / (6 * L) + 1e-12
    for l in range(L):
        for i in range(6):
            D[l, i, i] += reg


@kernel
def factor(R: np.ndarray, D: np.ndarray, lay: tuple, work: tuple) -> bool:
    """Factor the normal matrix at poses R[L,3,3]: per limb F[l] the Cholesky factor of its
    Schur complement and Z[l] = F[l]^-1 H[l, parent] (6x6); False if it is not positive definite.

    order: the non-root limbs, children before parents, then the root; joint_of[l]: the joint
    whose distal limb l is (of ``lay``); F, Z and the scratch C, Rrel, T ([6,6], [3,3], [3,6])
    are ``work``'s.
    """
    idx0, pad, a, wm0, ja, jb, p_a, p_b, wj, hj, axis, wh, order, joint_of, parent, radius, table, rms_tol = lay
    state, seen, fresh, y, D, F, Z, G, rms, nvis, info, C, Rrel, T, N, S = work
    F[:] = D
    for n in range(order.size - 1):
        l = order[n]
        q = joint_of[l]
        pa_l = ja[q]
        # Rrel = R_a^T R_b (parent a, child b = l)
        for i in range(3):
            for j in range(3):
                Rrel[i, j] = R[pa_l, 0, i] * R[l, 0, j] + R[pa_l, 1, i] * R[l, 1, j] + R[pa_l, 2, i] * R[l, 2, j]
        C[:] = 0.0
        _add_coupling(C, p_a[q], 1.0, Rrel, p_b[q], 1.0, wj[q], T)
        for h in range(hj.size):
            if hj[h] == q:
                _add_coupling(C, axis[h], 0.0, Rrel, axis[h], 0.0, wh[h], T)
        # C = H[parent, l]; Z = F_l^-1 C^T, then F_parent -= Z^T Z (still unfactored).
        if not _chol6(F[l]):
            return False
        for j in range(6):
            for i in range(6):
                Z[l, i, j] = C[j, i]
            _lower_solve_col(F[l], Z[l], j)
        p = parent[l]
        for i in range(6):
            for j in range(6):
                s = 0.0
                for k in range(6):
                    s += Z[l, k, i] * Z[l, k, j]
                F[p, i, j] -= s
    return _chol6(F[order[order.size - 1]])


@kernel
def _lower_solve_col(Lf: np.ndarray, X: np.ndarray, j: int) -> None:
    """Column j of X <- Lf^-1 (that column)."""
    for i in range(6):
        s = X[i, j]
        for k in range(i):
            s -= Lf[i, k] * X[k, j]
        X[i, j] = s / Lf[i, i]


@kernel
def solve(F: np.ndarray, Z: np.ndarray, order: np.ndarray, parent: np.ndarray, b: np.ndarray) -> None:
    """b[L,6] <- H^-1 b with the factor of :func:`factor` (leaves to root, then back)."""
    n = order.size
    for m in range(n - 1):
        l = order[m]
        _lower_solve(F[l], b[l])                     # t_l = F_l^-1 b_l
        p = parent[l]
        for i in range(6):                           # b_p -= Z_l^T t_l
            s = 0.0
            for k in range(6):
                s += Z[l, k, i] * b[l, k]
            b[p, i] -= s
    root = order[n - 1]
    _lower_solve(F[root], b[root])
    _upper_solve(F[root], b[root])
    for m in range(n - 2, -1, -1):
        l = order[m]
        p = parent[l]
        for i in range(6):                           # x_l = F_l^-T (t_l - Z_l x_p)
            s = 0.0
            for k in range(6):
                s += Z[l, i, k] * b[p, k]
            b[l, i] -= s
        _upper_solve(F[l], b[l])


@kernel
def _largest_eigenvalue4(N: np.ndarray, upper: float) -> float:
    """Largest eigenvalue of Horn's traceless symmetric 4x4 N: Newton's method on its
    characteristic polynomial l^4 + c2 l^2 + c1 l + c0 from ``upper`` (>= the eigenvalue, so the
    iterates fall monotonically onto it; Theobald 2005's QCP)."""
    t2 = 0.0
    t3 = 0.0
    for i in range(4):
        for j in range(4):
            t2 += N[i, j] * N[i, j]
            nn = 0.0
            for k in range(4):
                nn += N[i, k] * N[k, j]
            t3 += nn * N[j, i]
    c2 = -0.5 * t2
    c1 = -t3 / 3.0
    # det N by 2x2 minors of the first two rows and the last two
    s0 = N[0, 0] * N[1, 1] - N[1, 0] * N[0, 1]
    s1 = N[0, 0] * N[1, 2] - N[1, 0] * N[0, 2]
    s2 = N[0, 0] * N[1, 3] - N[1, 0] * N[0, 3]
    s3 = N[0, 1] * N[1, 2] - N[1, 1] * N[0, 2]
    s4 = N[0, 1] * N[1, 3] - N[1, 1] * N[0, 3]
    s5 = N[0, 2] * N[1, 3] - N[1, 2] * N[0, 3]
    k5 = N[2, 2] * N[3, 3] - N[3, 2] * N[2, 3]
    k4 = N[2, 1] * N[3, 3] - N[3, 1] * N[2, 3]
    k3 = N[2, 1] * N[3, 2] - N[3, 1] * N[2, 2]
    k2 = N[2, 0] * N[3, 3] - N[3, 0] * N[2, 3]
    k1 = N[2, 0] * N[3, 2] - N[3, 0] * N[2, 2]
    k0 = N[2, 0] * N[3, 1] - N[3, 0] * N[2, 1]
    c0 = s0 * k5 - s1 * k4 + s2 * k3 + s3 * k2 - s4 * k1 + s5 * k0
    lam = upper
    for _ in range(60):
        l2 = lam * lam
        p = (l2 + c2) * l2 + c1 * lam + c0
        dp = (4.0 * l2 + 2.0 * c2) * lam + c1
        if dp == 0.0:
            break
        nxt = lam - p / dp
        if abs(nxt - lam) <= 1e-15 * abs(nxt) or not nxt < lam:
            lam = nxt if nxt < lam else lam
            break
        lam = nxt
    return lam


@kernel
def own_rms(y: np.ndarray, seen: np.ndarray, a: np.ndarray, rms: np.ndarray, nvis: np.ndarray,
            N: np.ndarray, S: np.ndarray) -> None:
    """Each limb's own rigid-fit RMS (m, rms[L]) of its seen markers y[L,K,3] about their best
    pose, from the largest eigenvalue of Horn's (1987) 4x4 matrix of the centred covariance
    (Newton on its characteristic polynomial)
    (no pose is solved); nvis[L] the markers seen. N [4,4], S [3,3]: scratch."""
    L, K = seen.shape
    for l in range(L):
        # Two passes (centroids, then centred sums): world positions are metres from the
        # origin, so one-pass sums would cancel to a few digits of the millimetre residual.
        n = 0
        ca0 = ca1 = ca2 = cb0 = cb1 = cb2 = 0.0
        for k in range(K):
            if seen[l, k]:
                n += 1
                ca0 += a[l, k, 0]
                ca1 += a[l, k, 1]
                ca2 += a[l, k, 2]
                cb0 += y[l, k, 0]
                cb1 += y[l, k, 1]
                cb2 += y[l, k, 2]
        nvis[l] = n
        if n == 0:
            rms[l] = np.nan
            continue
        ca0, ca1, ca2, cb0, cb1, cb2 = ca0 / n, ca1 / n, ca2 / n, cb0 / n, cb1 / n, cb2 / n
        saa = sbb = 0.0
        S[:] = 0.0
        for k in range(K):
            if seen[l, k]:
                p0, p1, p2 = a[l, k, 0] - ca0, a[l, k, 1] - ca1, a[l, k, 2] - ca2
                q0, q1, q2 = y[l, k, 0] - cb0, y[l, k, 1] - cb1, y[l, k, 2] - cb2
                saa += p0 * p0 + p1 * p1 + p2 * p2
                sbb += q0 * q0 + q1 * q1 + q2 * q2
                S[0, 0] += p0 * q0
                S[0, 1] += p0 * q1
                S[0, 2] += p0 * q2
                S[1, 0] += p1 * q0
                S[1, 1] += p1 * q1
                S[1, 2] += p1 * q2
                S[2, 0] += p2 * q0
                S[2, 1] += p2 * q1
                S[2, 2] += p2 * q2
        trs = S[0, 0] + S[1, 1] + S[2, 2]
        N[0, 0] = trs
        N[0, 1] = N[1, 0] = S[1, 2] - S[2, 1]
        N[0, 2] = N[2, 0] = S[2, 0] - S[0, 2]
        N[0, 3] = N[3, 0] = S[0, 1] - S[1, 0]
        for i in range(3):
            for j in range(3):
                N[1 + i, 1 + j] = S[i, j] + S[j, i] - (trs if i == j else 0.0)
        # sqrt(saa sbb) >= the eigenvalue (Cauchy-Schwarz), and >= 0.
        best = _largest_eigenvalue4(N, np.sqrt(saa * sbb))
        v = saa + sbb - 2.0 * best
        rms[l] = np.sqrt((v if v > 0.0 else 0.0) / n)


@kernel
def gradient(R: np.ndarray, c: np.ndarray, y: np.ndarray, seen: np.ndarray, lay: tuple, G: np.ndarray) -> None:
    """G[L,6] = sum w B^T R^T r over every weighted residual r (markers, joints, hinges): the
    gradient of half the weighted squared residual in the limb-frame step coordinates (w, v)."""
    idx0, pad, a, wm0, ja, jb, p_a, p_b, wj, hj, axis, wh, order, joint_of, parent, radius, table, rms_tol = lay
    L, K = seen.shape
    G[:] = 0.0
    for l in range(L):
        for k in range(K):
            if seen[l, k]:
                _accumulate(G[l], R[l], a[l, k], 1.0, wm0[l, k],
                            R[l, 0, 0] * a[l, k, 0] + R[l, 0, 1] * a[l, k, 1] + R[l, 0, 2] * a[l, k, 2] + c[l, 0] - y[l, k, 0],
                            R[l, 1, 0] * a[l, k, 0] + R[l, 1, 1] * a[l, k, 1] + R[l, 1, 2] * a[l, k, 2] + c[l, 1] - y[l, k, 1],
                            R[l, 2, 0] * a[l, k, 0] + R[l, 2, 1] * a[l, k, 1] + R[l, 2, 2] * a[l, k, 2] + c[l, 2] - y[l, k, 2])
    for q in range(ja.size):
        A, B = ja[q], jb[q]
        e0 = (R[A, 0, 0] * p_a[q, 0] + R[A, 0, 1] * p_a[q, 1] + R[A, 0, 2] * p_a[q, 2] + c[A, 0]
              - R[B, 0, 0] * p_b[q, 0] - R[B, 0, 1] * p_b[q, 1] - R[B, 0, 2] * p_b[q, 2] - c[B, 0])
        e1 = (R[A, 1, 0] * p_a[q, 0] + R[A, 1, 1] * p_a[q, 1] + R[A, 1, 2] * p_a[q, 2] + c[A, 1]
              - R[B, 1, 0] * p_b[q, 0] - R[B, 1, 1] * p_b[q, 1] - R[B, 1, 2] * p_b[q, 2] - c[B, 1])
        e2 = (R[A, 2, 0] * p_a[q, 0] + R[A, 2, 1] * p_a[q, 1] + R[A, 2, 2] * p_a[q, 2] + c[A, 2]
              - R[B, 2, 0] * p_b[q, 0] - R[B, 2, 1] * p_b[q, 1] - R[B, 2, 2] * p_b[q, 2] - c[B, 2])
        _accumulate(G[A], R[A], p_a[q], 1.0, wj[q], e0, e1, e2)
        _accumulate(G[B], R[B], p_b[q], 1.0, -wj[q], e0, e1, e2)
    for h in range(hj.size):
        A, B = ja[hj[h]], jb[hj[h]]
        n = axis[h]
        e0 = (R[A, 0, 0] - R[B, 0, 0]) * n[0] + (R[A, 0, 1] - R[B, 0, 1]) * n[1] + (R[A, 0, 2] - R[B, 0, 2]) * n[2]
        e1 = (R[A, 1, 0] - R[B, 1, 0]) * n[0] + (R[A, 1, 1] - R[B, 1, 1]) * n[1] + (R[A, 1, 2] - R[B, 1, 2]) * n[2]
        e2 = (R[A, 2, 0] - R[B, 2, 0]) * n[0] + (R[A, 2, 1] - R[B, 2, 1]) * n[1] + (R[A, 2, 2] - R[B, 2, 2]) * n[2]
        _accumulate(G[A], R[A], n, 0.0, wh[h], e0, e1, e2)
        _accumulate(G[B], R[B], n, 0.0, -wh[h], e0, e1, e2)


@kernel
def _accumulate(g: np.ndarray, R: np.ndarray, p: np.ndarray, m: float, w: float,
                e0: float, e1: float, e2: float) -> None:
    """g[6] += w B^T R^T e: [p x (R^T e), m R^T e]."""
    r0 = R[0, 0] * e0 + R[1, 0] * e1 + R[2, 0] * e2
    r1 = R[0, 1] * e0 + R[1, 1] * e1 + R[2, 1] * e2
    r2 = R[0, 2] * e0 + R[1, 2] * e1 + R[2, 2] * e2
    g[0] += w * (p[1] * r2 - p[2] * r1)
    g[1] += w * (p[2] * r0 - p[0] * r2)
    g[2] += w * (p[0] * r1 - p[1] * r0)
    g[3] += w * m * r0
    g[4] += w * m * r1
    g[5] += w * m * r2


@kernel
def update_poses(R: np.ndarray, c: np.ndarray, x: np.ndarray, radius: np.ndarray, M: np.ndarray) -> float:
    """Apply the step -x[L,6] in each limb's frame (c <- c - R v, R <- R cay(-w)); returns the
    largest point motion it causes (m: |w| lever arm + |v|). M: 3x3 scratch."""
    L = R.shape[0]
    step = 0.0
    for l in range(L):
        w0, w1, w2, v0, v1, v2 = x[l, 0], x[l, 1], x[l, 2], x[l, 3], x[l, 4], x[l, 5]
        for i in range(3):
            c[l, i] -= R[l, i, 0] * v0 + R[l, i, 1] * v1 + R[l, i, 2] * v2
        sw = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
        sv = np.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
        # cay(-w) = I + f ([h]^2 - [h]), h = w / 2, f = 2 / (1 + |h|^2)
        h0, h1, h2 = 0.5 * w0, 0.5 * w1, 0.5 * w2
        f = 2.0 / (1.0 + 0.25 * sw * sw)
        M[0, 0] = 1.0 + f * (-h1 * h1 - h2 * h2)
        M[1, 1] = 1.0 + f * (-h0 * h0 - h2 * h2)
        M[2, 2] = 1.0 + f * (-h0 * h0 - h1 * h1)
        M[0, 1] = f * (h0 * h1 + h2)
        M[1, 0] = f * (h0 * h1 - h2)
        M[0, 2] = f * (h0 * h2 - h1)
        M[2, 0] = f * (h0 * h2 + h1)
        M[1, 2] = f * (h1 * h2 + h0)
        M[2, 1] = f * (h1 * h2 - h0)
        for i in range(3):
            r0, r1, r2 = R[l, i, 0], R[l, i, 1], R[l, i, 2]
            for j in range(3):
                R[l, i, j] = r0 * M[0, j] + r1 * M[1, j] + r2 * M[2, j]
        motion = sw * radius[l] + sv
        if motion > step:
            step = motion
    return step


@kernel
def track_frame(markers: np.ndarray, lay: tuple, work: tuple, R: np.ndarray, c: np.ndarray, tol: float,
                max_iterations: int) -> int:
    """Track one frame (markers float[M,3], NaN = unseen) from the last optimum R[L,3,3], c[L,3]
    (updated in place): iterations used (> 0), or a negative status (the frame is declined and
    the caller forgets the state): UNFIXABLE, NOT_POSITIVE, NOT_CONVERGED, POOR_FIT.

    ``lay``: the layout (:class:`Layout`); ``work`` (:class:`Work`): state[0] = 1 while F, Z factor the normal matrix for the seen markers seen[L,K] (int64);
    fresh, y: this frame's seen markers and their positions (zeros where unseen); D, F, Z, G,
    rms, nvis: diagonal blocks, factor, step, fit RMS (m), markers seen; info[0] the last step's
    largest point motion (m), info[1] the estimated distance left to the optimum (m, inf when no
    rate was seen); the rest is scratch.
    """
    idx0, pad, a, wm0, ja, jb, p_a, p_b, wj, hj, axis, wh, order, joint_of, parent, radius, table, rms_tol = lay
    state, seen, fresh, y, D, F, Z, G, rms, nvis, info, C, Rrel, T, N, S = work
    L, K = idx0.shape
    changed = state[0] == 0
    for l in range(L):
        for k in range(K):
            m = idx0[l, k]
            x0, x1, x2 = markers[m, 0], markers[m, 1], markers[m, 2]
            s = 1 if pad[l, k] and np.isfinite(x0) and np.isfinite(x1) and np.isfinite(x2) else 0
            fresh[l, k] = s
            if s:
                y[l, k, 0], y[l, k, 1], y[l, k, 2] = x0, x1, x2
            else:
                y[l, k, 0] = y[l, k, 1] = y[l, k, 2] = 0.0
            if s != seen[l, k]:
                changed = True
    if changed:
        for l in range(L):
            code = 0
            for k in range(K):
                if fresh[l, k]:
                    code += 1 << k
            if not table[l, code]:
                state[0] = 0
                return UNFIXABLE
        seen[:] = fresh
        diagonal_blocks(seen, lay, D)
        if not factor(R, D, lay, work):
            state[0] = 0
            return NOT_POSITIVE
        state[0] = 1
    it = 0
    last = np.inf
    while True:
        it += 1
        gradient(R, c, y, seen, lay, G)
        solve(F, Z, order, parent, G)
        step = update_poses(R, c, G, radius, Rrel)
        # Linear convergence (rate ~ this step / the last): stop once the step, or the estimated
        # distance to the optimum rate * step / (1 - rate), is within tolerance.
        rate = step / last
        info[0] = step
        info[1] = rate * step / (1.0 - rate) if 0.0 < rate < 1.0 else (0.0 if step == 0.0 else np.inf)
        if step <= tol or (0.0 < rate < 1.0 and rate * step <= (1.0 - rate) * tol):
            break
        if it >= max_iterations:
            state[0] = 0
            return NOT_CONVERGED
        last = step
        # The normal matrix at the new poses; it also serves the next frame's first step.
        if not factor(R, D, lay, work):
            state[0] = 0
            return NOT_POSITIVE
    own_rms(y, seen, a, rms, nvis, N, S)
    for l in range(L):
        if rms[l] > rms_tol[l]:
            state[0] = 0
            return POOR_FIT
    return it


class Layout(NamedTuple):
    """One layout's constant arrays (L limbs of up to K markers, J joints, H hinges)."""

    idx0: np.ndarray      # int64[L,K] marker of each limb slot (0 for padding)
    pad: np.ndarray       # int64[L,K] 1 where the slot holds a marker
    a: np.ndarray         # [L,K,3] m, markers in the limb frame about the base centroid
    wm0: np.ndarray       # [L,K] marker weights
    ja: np.ndarray        # int64[J] proximal limb of each joint
    jb: np.ndarray        # int64[J] distal limb
    p_a: np.ndarray       # [J,3] m, the joint in the proximal limb's frame
    p_b: np.ndarray       # [J,3] m, ... in the distal one's
    wj: np.ndarray        # [J] joint weights
    hj: np.ndarray        # int64[H] the joint of each hinge
    axis: np.ndarray      # [H,3] hinge axes
    wh: np.ndarray        # [H] hinge weights
    order: np.ndarray     # int64[L] non-root limbs children first, then the root
    joint_of: np.ndarray  # int64[L] the joint whose distal limb l is, -1 at the root
    parent: np.ndarray    # int64[L] parent limb, -1 at the root
    radius: np.ndarray    # [L] m, lever arm of a limb's rotation
    table: np.ndarray     # int64[L, 2^K] can the limb be fixed by this subset of its markers
    rms_tol: np.ndarray   # [L] m, worst acceptable own-marker fit RMS


class Work(NamedTuple):
    """The tracker's state, outputs and scratch for :func:`track_frame`."""

    state: np.ndarray   # int64[1] 1 while F, Z factor the normal matrix for ``seen``
    seen: np.ndarray    # int64[L,K]
    fresh: np.ndarray   # int64[L,K] this frame's seen markers
    y: np.ndarray       # [L,K,3] m, their positions (0 where unseen)
    D: np.ndarray       # [L,6,6] diagonal blocks
    F: np.ndarray       # [L,6,6] factor
    Z: np.ndarray       # [L,6,6]
    G: np.ndarray       # [L,6] gradient, then step
    rms: np.ndarray     # [L] m, own-marker fit RMS
    nvis: np.ndarray    # int64[L] markers seen
    info: np.ndarray    # [2] m: last step's largest point motion, estimated distance left
    C: np.ndarray       # [6,6] scratch
    Rrel: np.ndarray    # [3,3] scratch
    T: np.ndarray       # [3,6] scratch
    N: np.ndarray       # [4,4] scratch
    S: np.ndarray       # [3,3] scratch


class TrackBuffers:
    """The constant problem arrays (``lay``) and the preallocated state and scratch (``work``) of
    :func:`track_frame` for one layout (L limbs of up to K markers, J joints, H hinges)."""

    def __init__(self, idx: np.ndarray, a: np.ndarray, wm0: np.ndarray, ja: np.ndarray, jb: np.ndarray,
                 p_a: np.ndarray, p_b: np.ndarray, wj: np.ndarray, hj: np.ndarray, axis: np.ndarray,
                 wh: np.ndarray, order: np.ndarray, radius: np.ndarray, table: np.ndarray,
                 rms_tol: np.ndarray) -> None:
        f8 = lambda v: np.ascontiguousarray(v, dtype=np.float64)  # noqa: E731
        i8 = lambda v: np.ascontiguousarray(v, dtype=np.int64)    # noqa: E731
        L, K = idx.shape
        jb8 = i8(jb)
        joint_of = np.full(L, -1)
        joint_of[jb8] = np.arange(jb8.size)
        self.lay = Layout(i8(np.where(idx >= 0, idx, 0)), i8(idx >= 0), f8(a), f8(wm0), i8(ja), jb8, f8(p_a), f8(p_b),
                          f8(wj), i8(hj), f8(np.reshape(axis, (-1, 3))), f8(wh), i8(order), i8(joint_of),
                          i8(np.where(joint_of >= 0, i8(ja)[np.maximum(joint_of, 0)], -1)), f8(radius), i8(table),
                          f8(rms_tol))
        self.work = Work(np.zeros(1, dtype=np.int64), np.zeros((L, K), dtype=np.int64),
                         np.zeros((L, K), dtype=np.int64), np.zeros((L, K, 3)), np.zeros((L, 6, 6)),
                         np.zeros((L, 6, 6)), np.zeros((L, 6, 6)), np.zeros((L, 6)), np.zeros(L),
                         np.zeros(L, dtype=np.int64), np.zeros(2), np.zeros((6, 6)), np.zeros((3, 3)),
                         np.zeros((3, 6)), np.zeros((4, 4)), np.zeros((3, 3)))
        self._lay, self._work = tuple(self.lay), tuple(self.work)

    def track(self, markers: np.ndarray, R: np.ndarray, c: np.ndarray, tol: float, max_iterations: int) -> int:
        """track_frame on these buffers (R, c updated in place)."""
        return track_frame(markers, self._lay, self._work, R, c, tol, max_iterations)


def warm() -> None:
    """Compile every kernel once: a two-limb chain (three markers each, one hinged joint)."""
    a = np.array([[[0.05, 0.0, 0.0], [0.0, 0.05, 0.0], [0.0, 0.0, 0.05]]] * 2)
    idx = np.array([[0, 1, 2], [3, 4, 5]])
    buf = TrackBuffers(idx, a, np.full((2, 3), 1e6), np.array([0]), np.array([1]),
                       np.array([[0.0, 0.0, -0.2]]), np.array([[0.0, 0.0, 0.2]]), np.array([2.5e7]),
                       np.array([0]), np.array([[1.0, 0.0, 0.0]]), np.array([1e4]), np.array([1, 0]),
                       np.array([0.2, 0.2]), np.ones((2, 8)), np.array([0.01, 0.01]))
    R = np.repeat(np.eye(3)[None], 2, axis=0)
    c = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.6]])
    markers = np.concatenate([a[0] + c[0], a[1] + c[1]])
    buf.track(markers, R, c, 1e-5, 4)
    buf.track(readonly(markers), R, c, 1e-5, 4)   # a node's markers are decoded, read-only
