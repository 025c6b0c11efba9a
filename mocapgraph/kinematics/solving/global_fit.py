"""Global per-frame fit: all limb poses of a frame together by weighted least squares under the
joint constraints (Lu & O'Connor 1999, "global optimisation"; OpenSim IK and Vicon's kinematic
fit do the same), batched over frames.

Unknowns per limb: the rotation R and the world position c of its base-pose marker centroid, so
a base-pose point x is at ``R (x - c0) + c``. Residuals, each weighted by its inverse variance:

- every visible marker of the limb's fit set: ``R a + c - y`` (a = base marker - c0);
- every joint between limbs a and b: ``R_a p_a + c_a - R_b p_b - c_b`` (p = calibrated offsets,
  base joint - centroid): the two limbs meet at the joint (a stiff soft constraint);
- every hinge: ``R_a n - R_b n`` (n the calibrated axis): the limbs turn about it only.

Gauss-Newton from the segment-wise (Kabsch) poses, rotation steps ``R <- exp([w]) R``; a limb the
segment-wise fit could not place starts from its previous pose (warm start) and is held by its
joints and remaining markers. The limbs form a tree, so the normal matrix is block-tridiagonal
along it: it is solved by block elimination from the leaves to the root and back (6x6 blocks,
one batched step per tree level: O(limbs), no per-frame, per-limb or per-joint Python loops).
Frames step until no point is estimated to be more than ``tolerance`` from the optimum (only
the unconverged ones go on). Live frames are instead tracked from the previous frame's optimum
(:mod:`global_track`); this fit starts and restarts that tracking.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapgraph.kinematics.model import ActorModel
from mocapgraph.kinematics.quaternion import _SKEW, cross
from mocapgraph.kinematics.solving.rigid import gather_limb_markers


@dataclass
class GlobalFitOptions:
    """Weights as standard deviations: marker noise (m; per limb the calibrated fit RMS, at least
    this), joint agreement (m; reliable joints, and unreliable ones), hinge axis agreement (rad);
    Gauss-Newton iterations; frames per batched solve (bounds memory)."""

    marker_sigma_min: float = 0.0005
    joint_sigma: float = 0.0002
    unreliable_joint_sigma: float = 0.02
    hinge_sigma: float = 0.01
    iterations: int = 4
    tolerance: float = 1e-5
    chunk_frames: int = 128


class GlobalFit:
    """Refines segment-wise limb poses of [T] frames to the global weighted least-squares optimum."""

    def __init__(self, model: ActorModel, options: GlobalFitOptions | None = None) -> None:
        o = options or GlobalFitOptions()
        self.options = o
        idx = np.asarray(model.limb_markers)
        self._idx = idx
        self._c0 = np.asarray(model.limb_centroid, dtype=float)                     # [L,3]
        ref = gather_limb_markers(model.base_markers, idx)                            # [L,K,3]
        self._a = np.where((idx >= 0)[..., None], ref - self._c0[:, None], 0.0)       # [L,K,3]
        L = idx.shape[0]
        self.L = L
        sig = np.where(np.isfinite(model.limb_rms), model.limb_rms, 0.0)
        # A limb fitted through joint points (a two-marker or line-like cluster): its calibrated
        # RMS is mostly the points' error (the other limb's tilt times its lever arm), which the
        # joint terms here model; its own markers are as noisy as the capture's other markers.
        jp = np.asarray(model.limb_joint_points)
        pts = (jp >= 0).any(1) if jp.size else np.zeros(L, dtype=bool)
        own = ~pts & (sig > 0)
        if pts.any() and own.any():
            sig = np.where(pts, np.minimum(sig, np.median(sig[own])), sig)
        self._wm = (idx >= 0) / np.maximum(sig, o.marker_sigma_min)[:, None] ** 2    # [L,K]
        jl = np.asarray(model.joint_limbs)
        ok = (jl >= 0).all(1)
        self._ja, self._jb = jl[ok, 0], jl[ok, 1]
        self._p_a = np.asarray(model.offsets)[ok, 0]                                  # [J,3]
        self._p_b = np.asarray(model.offsets)[ok, 1]
        # Joints are held stiffly, as a kinematic model's are; one whose centre calibration could
        # not determine is held loosely so that it does not bend the limbs around a guess.
        rel = np.asarray(model.quality.reliable, dtype=bool)[ok]
        sj = np.where(rel, o.joint_sigma, o.unreliable_joint_sigma)
        self._wj = 1.0 / sj ** 2                                                      # [J]
        axes = np.asarray(model.hinge_axis)[ok]
        hing = np.asarray(model.joint_hinge, dtype=bool)[ok] & np.isfinite(axes).all(1)
        self._hj = np.flatnonzero(hing)
        self._axis = axes[hing]
        self._wh = np.full(self._hj.size, 1.0 / o.hinge_sigma ** 2)
        J = self._ja.size
        self._Ea = np.zeros((L, J))
        self._Ea[self._ja, np.arange(J)] = 1.0
        self._Eb = np.zeros((L, J))
        self._Eb[self._jb, np.arange(J)] = 1.0
        self._eye6 = np.eye(6)
        # Lever arm per limb (m): a rotation step of w rad moves its points up to |w| * radius.
        rad = np.sqrt(np.where(idx >= 0, (self._a ** 2).sum(-1), 0.0).max(1))
        np.maximum.at(rad, np.concatenate([self._ja, self._jb]),
                      np.sqrt((np.concatenate([self._p_a, self._p_b]) ** 2).sum(-1)))
        self._radius = np.maximum(rad, 0.05)
        # Tree levels for the block elimination: (limbs, their joints, parents, incidence) per
        # depth, deepest first; a limb's joint is the one whose distal limb it is.
        parent = np.asarray(model.limb_parent)
        depth = np.zeros(L, dtype=int)
        for l in range(L):
            p, d = parent[l], 0
            while p >= 0 and d <= L:
                p, d = parent[p], d + 1
            depth[l] = d
        joint_of = {int(b): k for k, b in enumerate(self._jb)}
        roots = np.flatnonzero(depth == 0)
        if roots.size != 1 or any(l not in joint_of for l in range(L) if depth[l] > 0) \
                or any(parent[self._jb[k]] != self._ja[k] for k in range(J)):
            raise ValueError("global fit needs a limb tree whose joints join each limb to its parent")
        self._root = int(roots[0])
        self._levels = []
        for d in range(depth.max(), 0, -1):
            limbs = np.flatnonzero(depth == d)
            ups, where = np.unique(parent[limbs], return_inverse=True)
            inc = np.zeros((ups.size, limbs.size))
            inc[where, np.arange(limbs.size)] = 1.0
            self._levels.append((limbs, np.array([joint_of[int(l)] for l in limbs]), parent[limbs], ups, inc))
        self._last: tuple[np.ndarray, np.ndarray] | None = None   # warm start: previous poses

    def reset(self) -> None:
        """Forget the previous frame's poses."""
        self._last = None

    def remember(self, rot: np.ndarray, cen: np.ndarray) -> None:
        """A frame solved elsewhere (the live tracker): its poses (rot [L,3,3], base-marker
        centroids cen [L,3]) are the warm start for limbs a later frame cannot place."""
        self._last = (rot, cen)

    # ---- warm start ------------------------------------------------------------------------
    def _initial(self, rot: np.ndarray, cen: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Kabsch poses where valid; elsewhere the latest earlier pose (this batch, then the last
        call), else the base pose."""
        T, L = valid.shape
        if self._last is not None:
            prev_r, prev_c = self._last
        else:
            prev_r, prev_c = np.broadcast_to(np.eye(3), (L, 3, 3)), self._c0
        rot = np.concatenate([prev_r[None], np.where(valid[..., None, None], rot, 0.0)])
        cen = np.concatenate([prev_c[None], np.where(valid[..., None], cen, 0.0)])
        has = np.concatenate([np.ones((1, L), dtype=bool), valid])
        src = np.maximum.accumulate(np.where(has, np.arange(T + 1)[:, None], 0), axis=0)[1:]   # [T,L]
        lidx = np.arange(L)[None, :]
        return rot[src, lidx], cen[src, lidx]

    # ---- the fit ---------------------------------------------------------------------------
    def refine(self, markers: np.ndarray, rot: np.ndarray, trans: np.ndarray, valid: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """markers float[T,M,3]; segment-wise rot [T,L,3,3], trans [T,L,3] (``x = R x_ref + t``),
        valid bool[T,L] -> globally fitted (rot, trans) in the same convention, every limb set."""
        out = []
        n = max(1, int(self.options.chunk_frames))
        for a in range(0, valid.shape[0], n):
            out.append(self._refine(markers[a:a + n], rot[a:a + n], trans[a:a + n], valid[a:a + n]))
        return tuple(np.concatenate(x) for x in zip(*out))

    def _refine(self, markers, rot, trans, valid):
        T, L = valid.shape
        cen = (rot @ self._c0[:, :, None])[..., 0] + trans
        r, c = self._initial(rot, cen, valid)
        y = gather_limb_markers(markers, self._idx)                                   # [T,L,K,3]
        seen = np.isfinite(y).all(-1)
        wm = np.where(seen, self._wm, 0.0)                                            # [T,L,K]
        y = np.where(seen[..., None], y, 0.0)
        wsum = wm.sum(-1)                                                             # [T,L]
        # Only the frames whose last step still moved a point go on (a convergence test).
        r, c = r.copy(), c.copy()
        act = np.arange(T)
        last = np.full((T, L), np.inf)
        tol = self.options.tolerance
        for _ in range(max(1, self.options.iterations)):
            r[act], c[act], moved = self._step(r[act], c[act], y[act], wm[act], wsum[act])
            # Linear convergence (rate ~ this step / the last, per limb): a frame is done once
            # every limb's last step, or its estimated distance to the optimum, is within tol.
            rate = moved / last[act]                                                 # 0 on the first step
            left = np.where((rate > 0.0) & (rate < 1.0), rate * moved / np.maximum(1.0 - rate, 1e-12), np.inf)
            going = ~(np.minimum(left, moved) <= tol).all(1)
            last[act] = moved
            act = act[going]
            if not act.size:
                break
        self._update_last(rot, cen, valid)
        return r, c - (r @ self._c0[:, :, None])[..., 0]

    def _update_last(self, rot, cen, valid) -> None:
        """The warm start for the next call: per limb its latest segment-wise pose (so that a
        batch and the same frames stepped live start, and end, alike)."""
        has = valid.any(0)
        last = valid.shape[0] - 1 - np.argmax(valid[::-1], axis=0)                    # [L]
        li = np.arange(valid.shape[1])
        if self._last is None:
            prev_r, prev_c = np.broadcast_to(np.eye(3), rot.shape[1:]).copy(), self._c0.copy()
        else:
            prev_r, prev_c = self._last
        self._last = (np.where(has[:, None, None], rot[last, li], prev_r),
                      np.where(has[:, None], cen[last, li], prev_c))

    def _step(self, r, c, y, wm, wsum):
        """One Gauss-Newton step of every frame's poses (r [T,L,3,3], c [T,L,3]) -> new poses and
        how far each limb's points moved (m, [T,L])."""
        T, L = r.shape[:2]
        ja, jb, hj = self._ja, self._jb, self._hj
        J = ja.size
        eye3 = np.eye(3)
        wj = self._wj[None, :, None, None]
        # markers: H_ww = sum w (|q|^2 I - q q^T), H_wc = sum w [q]x, H_cc = sum w I
        q = self._a @ np.swapaxes(r, -1, -2)                                       # [T,L,K,3]
        res = q + c[:, :, None] - y
        wq = wm[..., None] * q
        diag = np.empty((T, L, 6, 6))
        diag[..., :3, :3] = (wq * q).sum((-1, -2))[..., None, None] * eye3 - np.swapaxes(wq, -1, -2) @ q
        sq = _skew(wq.sum(2))
        diag[..., :3, 3:] = sq
        diag[..., 3:, :3] = -sq
        diag[..., 3:, 3:] = wsum[..., None, None] * eye3
        g = np.concatenate([cross(wq, res).sum(2), (wm[..., None] * res).sum(2)], -1)   # [T,L,6]
        # joints: e = q_a + c_a - q_b - c_b, J_a = [-[q_a]x, I], J_b = [[q_b]x, -I]
        qa = (r[:, ja] @ self._p_a[..., None])[..., 0]
        qb = (r[:, jb] @ self._p_b[..., None])[..., 0]
        e = qa + c[:, ja] - qb - c[:, jb]                                         # [T,J,3]
        eye = np.broadcast_to(eye3, (T, J, 3, 3))
        Ja = np.concatenate([-_skew(qa), eye], -1)                                # [T,J,3,6]
        Jb = np.concatenate([_skew(qb), -eye], -1)
        JaT, JbT = np.swapaxes(Ja, -1, -2), np.swapaxes(Jb, -1, -2)
        haa, hbb, hab = wj * (JaT @ Ja), wj * (JbT @ Jb), wj * (JaT @ Jb)
        ga = wj[..., 0] * (JaT @ e[..., None])[..., 0]
        gb = wj[..., 0] * (JbT @ e[..., None])[..., 0]
        if hj.size:
            # hinges: e = u_a - u_b (u = R n), J_a = [-[u_a]x, 0], J_b = [[u_b]x, 0]
            ua = np.einsum("thik,hk->thi", r[:, ja[hj]], self._axis)
            ub = np.einsum("thik,hk->thi", r[:, jb[hj]], self._axis)
            eh = (ua - ub)[..., None]
            Sa, Sb = _skew(ua), _skew(ub)
            wh = self._wh[None, :, None, None]
            haa[:, hj, :3, :3] -= wh * (Sa @ Sa)
            hbb[:, hj, :3, :3] -= wh * (Sb @ Sb)
            hab[:, hj, :3, :3] += wh * (Sa @ Sb)
            ga[:, hj, :3] += wh[..., 0] * (Sa @ eh)[..., 0]
            gb[:, hj, :3] -= wh[..., 0] * (Sb @ eh)[..., 0]
        # Each limb but the root is the distal side of exactly one joint; parents may repeat.
        diag[:, jb] += hbb
        g[:, jb] += gb
        diag += (self._Ea @ haa.reshape(T, J, 36)).reshape(T, L, 6, 6)
        g += self._Ea @ ga
        # Directions no residual sees (a limb's spin about its only marker-joint line) stay put.
        tr = np.einsum("tlii->tl", diag)[..., None, None] / 6.0
        diag = diag + (1e-9 * tr + 1e-12) * self._eye6
        step = self._tree_solve(diag, hab, -g)
        w, v = step[..., :3], step[..., 3:]
        moved = np.sqrt((v * v).sum(-1)) + np.sqrt((w * w).sum(-1)) * self._radius   # [T,L] m
        return _rotvec_matrix(w) @ r, c + v, moved

    def _tree_solve(self, diag: np.ndarray, hab: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Solve the block tree system (diag [T,L,6,6], parent-child blocks hab [T,J,6,6] =
        H[parent, child] per joint, right side b [T,L,6]) by elimination leaves -> root -> leaves."""
        D, b = diag.copy(), b.copy()
        saved = []
        T = D.shape[0]
        for limbs, joints, parents, ups, inc in self._levels:  # deepest level first
            Dinv = np.linalg.inv(D[:, limbs])                   # [T,n,6,6]
            B = hab[:, joints]                                  # H[parent, child]
            BD = B @ Dinv
            n = limbs.size
            D[:, ups] -= (inc @ (BD @ np.swapaxes(B, -1, -2)).reshape(T, n, 36)).reshape(T, ups.size, 6, 6)
            b[:, ups] -= inc @ (BD @ b[:, limbs, :, None])[..., 0]
            saved.append((limbs, joints, parents, Dinv))
        x = np.zeros_like(b)
        root = self._root
        x[:, root] = np.linalg.solve(D[:, root], b[:, root, :, None])[..., 0]
        for limbs, joints, parents, Dinv in reversed(saved):
            rhs = b[:, limbs] - (np.swapaxes(hab[:, joints], -1, -2) @ x[:, parents, :, None])[..., 0]
            x[:, limbs] = (Dinv @ rhs[..., None])[..., 0]
        return x


def _skew(v: np.ndarray) -> np.ndarray:
    """[...,3] -> [...,3,3] with skew(v) @ u = v x u (one matrix product: this runs ~6 times a step)."""
    return (v @ _SKEW).reshape(v.shape[:-1] + (3, 3))


def _rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrices [...,3,3] of rotation vectors w [...,3] (Rodrigues)."""
    th = np.sqrt((w * w).sum(-1))[..., None, None]
    k = _skew(w)
    small = th < 1e-8
    s = np.where(small, 1.0, np.sin(th) / np.where(small, 1.0, th))
    c = np.where(small, 0.5, (1.0 - np.cos(th)) / np.where(small, 1.0, th * th))
    return np.eye(3) + s * k + c * (k @ k)
