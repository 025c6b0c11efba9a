"""Live global fit in numpy: the reference of the compiled tracker, and the tracker of wide layouts.

The same weighted least-squares problem as :mod:`mocapgraph.kinematics.solving.global_fit` (markers,
joints, hinges; its weights), solved for a live frame starting from the last frame's optimum
instead of a fresh segment-wise (Kabsch) guess, so a frame needs no SVD. What keeps a frame to a
few dozen small numpy calls:

- poses step in the limb's own frame (``R <- R cay(w)``, ``c <- c + R v``): the normal matrix's
  diagonal blocks are then constant for a set of seen markers and only the joints' coupling
  blocks depend on the poses (through the relative rotations); it is assembled dense (6L x 6L)
  and Cholesky-factored by LAPACK in one call, and the factor made after a frame's first step
  also serves the next frame's first step (a few milliseconds of motion older);
- the residuals are linear in the stacked state [R, c] of every limb: markers, joint points
  and hinge axes are one matrix product, and so is the gradient.

Steps stop when the estimated distance to the optimum (from the observed linear convergence
rate) or the last step is within ``tolerance`` (m of point motion). The tracker declines a frame
(returns None; the caller solves it from the segment-wise fit and reseeds it) when it has no good
last frame, a limb cannot be fixed by its own markers, a limb's fit is poor, or the steps do not
converge.

:class:`.global_track.GlobalTracker` runs each frame as one compiled call of
:func:`global_fit_kernels.track_frame` (the same steps, the normal matrix factored by 6x6 blocks
along the limb tree); this numpy code is its reference (the tests hold the two to the same joint
centres) and runs the layouts the kernel cannot take (more than 8 markers a limb: the kernel tables
every subset of a limb's markers), and a solver built with ``compiled=False``.
"""
from __future__ import annotations

import numpy as np

from scipy.linalg.lapack import dpotrf, dpotrs

from mocapgraph.kinematics.solving.global_fit import GlobalFit, _skew
from mocapgraph.kinematics.solving.global_track import Tracked, lever_radius, visibility_table
from mocapgraph.kinematics.solving.rigid import fit_rigid


class NumpyGlobalTracker:
    """Warm-started live global fit over one frame at a time, in numpy (see the module docstring).

    rms_tol: float[L] m, a limb fit worse than this makes the tracker decline the frame;
    tolerance: m of point motion (see :mod:`.global_track`); max_iterations per frame.
    """

    def __init__(self, fit: GlobalFit, rms_tol: np.ndarray, tolerance: float = 1e-5,
                 max_iterations: int = 4) -> None:
        self.tolerance = float(tolerance)
        self.max_iterations = int(max_iterations)
        self._rms_tol = np.asarray(rms_tol, dtype=float)
        idx = fit._idx
        L, K = idx.shape
        self.L, self.K = L, K
        self._pad = idx >= 0
        self._idx0 = np.where(self._pad, idx, 0)
        self._c0 = fit._c0
        self._a = fit._a                                                         # [L,K,3]
        ja, jb, hj = fit._ja, fit._jb, fit._hj
        J, H = ja.size, hj.size
        LK = L * K
        # The point list: markers (L*K, padding included with weight 0), the joints' two sides,
        # the hinges' two axis copies (directions: no translation part).
        limb = np.concatenate([np.repeat(np.arange(L), K), ja, jb, ja[hj], jb[hj]])
        local = np.concatenate([fit._a.reshape(LK, 3), fit._p_a, fit._p_b, fit._axis, fit._axis])
        move = np.concatenate([np.ones(LK + 2 * J), np.zeros(2 * H)])
        P = limb.size
        # Residual rows: one per marker (point - target), one per joint and hinge (side a - side b).
        R_ = LK + J + H
        S = np.zeros((R_, P))
        S[np.arange(LK), np.arange(LK)] = 1.0
        rj = LK + np.arange(J)
        S[rj, LK + np.arange(J)] = 1.0
        S[rj, LK + J + np.arange(J)] = -1.0
        rh = LK + J + np.arange(H)
        S[rh, LK + 2 * J + np.arange(H)] = 1.0
        S[rh, LK + 2 * J + H + np.arange(H)] = -1.0
        # Residuals are linear in the stacked state X = [R (row-major), c] per limb [L,12]:
        # world_p[i] = sum_j R[i,j] p[j] + m c[i]. One matrix M maps X to every residual.
        A = np.zeros((P, 3, L, 12))
        pi = np.arange(P)
        for i in range(3):
            A[pi, i, limb, 3 * i:3 * i + 3] = local
            A[pi, i, limb, 9 + i] = move
        M = np.einsum("rp,piq->riq", S, A.reshape(P, 3, L * 12)).reshape(3 * R_, L * 12)
        self._M, self._MT = M, np.ascontiguousarray(M.T)
        self._LK = LK
        self._w_fixed = np.concatenate([fit._wj, fit._wh])                       # joint, hinge rows
        self._wm0 = fit._wm.reshape(LK)
        # Point Jacobians in the limb frame, B = [-[p]x, m I] (3x6); world ones are R B.
        B = np.concatenate([-_skew(local), move[:, None, None] * np.eye(3)], -1)   # [P,3,6]
        self._BT = np.ascontiguousarray(np.swapaxes(B, -1, -2))                  # [P,6,3]
        self._BB = (self._BT @ B).reshape(P, 36)
        E = np.zeros((L, P))
        E[limb, np.arange(P)] = 1.0
        self._E = E
        # Pairs (joint and hinge rows) couple limbs a and b: H[a,b] -= w B_a^T R_a^T R_b B_b.
        pa = np.concatenate([LK + np.arange(J), LK + 2 * J + np.arange(H)])
        pb = np.concatenate([LK + J + np.arange(J), LK + 2 * J + H + np.arange(H)])
        self._pair_a, self._pair_b = limb[pa], limb[pb]
        self._BTa_w, self._Bb = -self._w_fixed[:, None, None] * self._BT[pa], B[pb]
        # Row weight per point (each point is in exactly one row): markers' are per frame.
        self._u_fixed = np.concatenate([fit._wj, fit._wj, fit._wh, fit._wh])
        # Every joint's pair (a, b) is a parent-child edge; hinges reuse their joint's edge.
        self._edge_of_pair = np.concatenate([np.arange(J), hj])
        Ep = np.zeros((J, J + H))
        Ep[self._edge_of_pair, np.arange(J + H)] = 1.0
        self._Ep = Ep
        # Where each edge's 6x6 coupling block goes in the flat 6L x 6L matrix, and its transpose.
        i6 = np.arange(6)
        n6 = 6 * L
        self._flat_ab = ((6 * ja[:, None, None] + i6[:, None]) * n6 + 6 * jb[:, None, None] + i6).reshape(J, 36)
        self._flat_ba = ((6 * jb[:, None, None] + i6) * n6 + 6 * ja[:, None, None] + i6[:, None]).reshape(J, 36)
        self._radius = lever_radius(fit)                                         # [L] m lever arm
        self._lever = np.stack([self._radius, np.ones(L)], 1)                    # |w|, |v| -> motion
        # tr(A [w]x) = (A.flat @ V) . w: the limb-frame rotation gradient from dC/dR.
        self._V = np.stack([_skew(np.eye(3)[k]).T.reshape(9) for k in range(3)], 1)
        self._bits = (1 << np.arange(K))
        # Up to 8 markers a limb, every subset's answer is tabled; beyond, it is worked out
        # whenever the set of seen markers changes.
        self._valid_table = visibility_table(fit) if K <= 8 else None
        self._Y = np.zeros(3 * R_)
        self._all_valid = np.ones(L, dtype=bool)
        self._W = np.repeat(np.concatenate([np.zeros(LK), self._w_fixed]), 3)
        self.reset()

    def _fixable(self, seen: np.ndarray) -> bool:
        """Can every limb be fixed by its seen markers (seen bool[L,K]) alone?"""
        if self._valid_table is not None:
            return bool(self._valid_table[np.arange(self.L), seen @ self._bits].all())
        a = np.where(self._pad[..., None], self._a, np.nan)
        return bool(fit_rigid(a, a, seen.astype(float)).valid.all())

    def reset(self) -> None:
        """Forget the last frames (the next frame is declined)."""
        self._R = self._c = None
        self._chol = None
        self._code = None

    # ---- state handed over from the full fit ------------------------------------------------
    def seed(self, rot: np.ndarray, trans: np.ndarray, good: bool) -> None:
        """The frame just solved by the full fit (rot [L,3,3], trans [L,3]); good: every limb was
        fixed by its markers and fit well. A bad frame leaves nothing to start from."""
        if not good:
            self.reset()
            return
        c = (rot @ self._c0[:, :, None])[..., 0] + trans
        self._R, self._c = np.ascontiguousarray(rot, dtype=np.float64).copy(), np.ascontiguousarray(c, dtype=np.float64)

    # ---- the normal matrix --------------------------------------------------------------------
    def _new_markers(self, seen: np.ndarray, u_markers: np.ndarray) -> None:
        """Another set of seen markers: the normal matrix's diagonal blocks (constant while the
        set holds) and the limbs' own-marker sums for the fit RMS."""
        L, n6 = self.L, 6 * self.L
        u = np.concatenate([u_markers, self._u_fixed])
        D = (self._E @ (u[:, None] * self._BB)).reshape(L, 6, 6)
        H = np.zeros((L, 6, L, 6))
        H[np.arange(L), :, np.arange(L)] = D
        H = H.reshape(n6, n6)
        # Directions no residual sees stay put (as in the batch fit); the coupling blocks add
        # nothing to the trace.
        H[np.diag_indices(n6)] += 1e-9 * np.trace(H) / n6 + 1e-12
        self._Hbase = H
        m = seen[..., None]
        a = np.where(m, self._a, 0.0)
        n = seen.sum(1)
        ca = a.sum(1) / n[:, None]
        self._own = (np.ascontiguousarray(np.swapaxes(a, 1, 2)), ca, n,
                     (a * a).sum((1, 2)) - n * (ca * ca).sum(1))

    def _refresh(self, R: np.ndarray) -> None:
        """Factor the normal matrix at poses R: the coupling blocks H[a,b] = -w B_a^T R_a^T R_b B_b."""
        Rrel = np.swapaxes(R[self._pair_a], -1, -2) @ R[self._pair_b]
        off = self._Ep @ (self._BTa_w @ Rrel @ self._Bb).reshape(-1, 36)
        H = self._Hbase.copy()
        flat = H.reshape(-1)
        flat[self._flat_ab] = off
        flat[self._flat_ba] = off
        chol, info = dpotrf(H, lower=False, clean=False, overwrite_a=True)
        self._chol = chol if info == 0 else None

    def _own_rms(self, y: np.ndarray, seen: np.ndarray) -> np.ndarray:
        """Each limb's segment-wise fit RMS (m; its seen markers y [L,K,3] about their best rigid
        pose, as the batch path reports) without solving for that pose: min sum |b - R a|^2 =
        sum |a|^2 + sum |b|^2 - 2 max_R sum b . R a, and the maximum is the largest eigenvalue
        of Horn's (1987) symmetric 4x4 matrix of the centred covariance sum a b^T."""
        aT, ca, n, saa = self._own
        b = np.where(seen[..., None], y, 0.0)
        cb = b.sum(1) / n[:, None]
        h = aT @ b - n[:, None, None] * (ca[:, :, None] * cb[:, None, :])          # [L,3,3]
        ss = saa + (b * b).sum((1, 2)) - n * (cb * cb).sum(1)
        best = np.linalg.eigvalsh((h.reshape(-1, 9) @ _HORN).reshape(-1, 4, 4))[:, 3]
        return np.sqrt(np.maximum(ss - 2.0 * best, 0.0) / n)

    # ---- one frame -----------------------------------------------------------------------------
    def track(self, markers: np.ndarray) -> Tracked | None:
        """markers float[M,3] (NaN = unseen) -> the frame's global optimum, or None (declined)."""
        if self._R is None:
            return None
        y = markers[self._idx0]                                                   # [L,K,3]
        seen = np.isfinite(y).all(-1) & self._pad
        LK, L = self._LK, self.L
        self._Y[:3 * LK] = np.where(seen[..., None], y, 0.0).reshape(-1)
        R, c = self._R, self._c
        key = seen.tobytes()
        if self._chol is None or key != self._code:
            if not self._fixable(seen):
                self.reset()
                return None
            self._code = key
            u = self._wm0 * seen.reshape(LK)
            self._W[:3 * LK] = np.repeat(u, 3)
            self._new_markers(seen, u)
            self._refresh(R)
            if self._chol is None:
                self.reset()
                return None
        X = np.empty((L, 12))
        it, last, tol = 0, np.inf, self.tolerance
        while True:
            it += 1
            X[:, :9] = R.reshape(L, 9)
            X[:, 9:] = c
            res = self._M @ X.reshape(-1) - self._Y                                  # [3 rows]
            gX = (self._MT @ (self._W * res)).reshape(L, 12)                          # dC/dX
            a = np.swapaxes(gX[:, :9].reshape(L, 3, 3), -1, -2) @ R                   # (dC/dR)^T R
            G = np.concatenate([a.reshape(L, 9) @ self._V, (gX[:, None, 9:] @ R)[:, 0]], 1)
            # The step is minus this solution: applied as c - R v and R cay(-w).
            x = dpotrs(self._chol, G.reshape(-1), lower=False)[0].reshape(L, 6)
            c = c - (R @ x[:, 3:, None])[..., 0]
            sq = np.sqrt((x * x).reshape(L, 2, 3).sum(-1))                            # |w|, |v|
            R = R @ _cayley_neg(x[:, :3], sq[:, 0])
            step = float((sq * self._lever).sum(1).max())                             # largest point motion, m
            # Gauss-Newton converges linearly here (rate ~ this step / the last): stop once the
            # step, or the estimated distance to the optimum rate * step / (1 - rate), is within
            # tolerance.
            rate = step / last                                                       # 0 on the first step
            if step <= tol or 0.0 < rate < 1.0 and rate * step <= (1.0 - rate) * tol:
                break
            if it >= self.max_iterations:
                self.reset()
                return None
            last = step
            # The normal matrix at the new poses (it depends on them through the relative
            # rotations at the joints, which the stiff joint terms make matter): it also
            # serves the next frame's first step.
            self._refresh(R)
            if self._chol is None:
                self.reset()
                return None
        rms = self._own_rms(y, seen)
        if (rms > self._rms_tol).any():
            self.reset()
            return None
        self._R, self._c = R, c
        trans = c - (R @ self._c0[..., None])[..., 0]
        return Tracked(R, trans, c, self._all_valid, rms, self._own[2], it)


def _cayley_neg(w: np.ndarray, size: np.ndarray) -> np.ndarray:
    """cay(-w) [L,3,3] for rotation vectors w [L,3] of length ``size`` [L] (the Cayley map: exact
    rotations, equal to exp(-[w]x) to second order, so a Gauss-Newton step keeps its fixed
    point): I + f ([h]^2 - [h]), h = w / 2, f = 2 / (1 + |h|^2)."""
    k = _skew(0.5 * w)
    f = (2.0 / (1.0 + 0.25 * size * size))[:, None, None]
    return _EYE3 + f * (k @ k - k)


_EYE3 = np.eye(3)
# Horn's matrix N (row-major 4x4) as a linear map of the covariance S (row-major 3x3, S_ij =
# sum a_i b_j): N = [[tr S, D^T], [D, S + S^T - tr S I]], D = (S_yz - S_zy, S_zx - S_xz, S_xy - S_yx).
_HORN = np.zeros((9, 16))
for _i in range(3):
    _HORN[4 * _i, 0] = 1.0
    for _k in range(3):
        _HORN[4 * _i, 5 * (_k + 1)] = 1.0 if _k == _i else -1.0
for (_r, _c), _terms in {(0, 1): ((5, 1), (7, -1)), (0, 2): ((6, 1), (2, -1)), (0, 3): ((1, 1), (3, -1)),
                         (1, 2): ((1, 1), (3, 1)), (1, 3): ((6, 1), (2, 1)), (2, 3): ((5, 1), (7, 1))}.items():
    for _e, _sgn in _terms:
        _HORN[_e, 4 * _r + _c] += _sgn
        _HORN[_e, 4 * _c + _r] += _sgn
