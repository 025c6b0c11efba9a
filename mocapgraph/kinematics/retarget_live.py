"""The retargeter's one-frame path: :meth:`Retargeter.process` for a single frame, constants folded at setup.

Same math and same output as the batched path (to rounding, checked in the tests), but with the
world-frame rotations as wxyz quaternions and everything that does not change per frame folded
into constant arrays when the retargeter is built:

* Eq 4.1's constant factors: Δ = A·Q_k·D·R⁻¹·A⁻¹ is a fixed 4x4 matrix per joint acting on Q_k
  (a quaternion product with a constant is linear); with no source dependencies one matrix product
  does the gather of every Q_k and all of Eq 4.1;
* rotating a constant vector v by a unit quaternion q is a fixed quadratic form in q (16 x 3), so
  every bone of the forward kinematics is one product of the quaternions' outer products with a
  constant tensor, and the ancestor sum one matrix product more;
* inheritance and rest orientations (W = Δ[nearest driven] · rest_world) are one constant linear
  map; the local rotations (rest⁻¹ · W[parent]⁻¹ · W) one bilinear form.

A numpy call costs microseconds whatever its size, so what counts is the number of calls: a frame
is a few dozen, none per joint. Joint quality is the batched path's own code, skipped when every
input is good (then every joint is good).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from .quaternion import matrix_to_quat, quat_multiply, quat_to_matrix
from .foot_planting import plant_one
from .retarget_source import pelvis_hips, rotations_from_points_frame

if TYPE_CHECKING:
    from .retarget import Retargeter

QUALITY_GOOD = 2
_E4 = np.eye(4)
# Hamilton product as a bilinear form: (a ⊗ b).reshape(16) @ _HAM = a * b
_HAM = np.stack([quat_multiply(_E4[k], _E4[l]) for k in range(4) for l in range(4)])        # [16, 4]
_CONJ16 = np.repeat([1.0, -1.0, -1.0, -1.0], 4)[:, None]                                   # a -> conj(a)
_ID = np.array([1.0, 0.0, 0.0, 0.0])
_PHASE = np.array([0.0, -0.5 * np.pi])     # cos(h - pi/2) = sin(h)
_ONES4 = np.ones(4)
_ONES3 = np.ones(3)
_N2_LO, _N2_HI = (1.0 - 1e-3) ** 2, (1.0 + 1e-3) ** 2   # |q| within 1e-3 of 1, squared
# rotation matrix of a unit q as a quadratic form: R(q)[r, c] = sum_ab q_a q_b _ROT[4a+b, r, c]
_ROT = np.zeros((16, 3, 3))
for (_r, _c), _ts in {
        (0, 0): [(0, 0, 1), (1, 1, 1), (2, 2, -1), (3, 3, -1)], (1, 1): [(0, 0, 1), (1, 1, -1), (2, 2, 1), (3, 3, -1)],
        (2, 2): [(0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, 1)],
        (0, 1): [(1, 2, 2), (0, 3, -2)], (1, 0): [(1, 2, 2), (0, 3, 2)], (0, 2): [(1, 3, 2), (0, 2, 2)],
        (2, 0): [(1, 3, 2), (0, 2, -2)], (1, 2): [(2, 3, 2), (0, 1, -2)], (2, 1): [(2, 3, 2), (0, 1, 2)]}.items():
    for _a, _b, _k in _ts:
        _ROT[4 * _a + _b, _r, _c] += _k
# a · b and a x b from the outer product a ⊗ b [9]: [dot, cross]
_DOTCROSS = np.zeros((9, 4))
_DOTCROSS[[0, 4, 8], 0] = 1.0
for _i, (_j, _k) in enumerate(((1, 2), (2, 0), (0, 1))):
    _DOTCROSS[3 * _j + _k, 1 + _i] += 1.0
    _DOTCROSS[3 * _k + _j, 1 + _i] -= 1.0


def _left(p: np.ndarray) -> np.ndarray:
    """4x4 matrix of q -> p * q."""
    return np.einsum("kli,k->il", _HAM.reshape(4, 4, 4), p)


def _right(p: np.ndarray) -> np.ndarray:
    """4x4 matrix of q -> q * p."""
    return np.einsum("kli,l->ik", _HAM.reshape(4, 4, 4), p)


def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a * b for [n, 4] arrays: one broadcast and one matrix product."""
    return (a[:, :, None] * b[:, None, :]).reshape(-1, 16) @ _HAM


def _rotate_const(q: np.ndarray, forms: np.ndarray) -> np.ndarray:
    """R(q[i]) v[i] for unit q [n, 4], with forms [n, 16, 3] = _ROT @ v[i] precomputed."""
    return ((q[:, :, None] * q[:, None, :]).reshape(-1, 1, 16) @ forms)[:, 0]


def _between(a: np.ndarray, b: np.ndarray, a_len: np.ndarray | None = None,
             b_len2: np.ndarray | None = None) -> np.ndarray:
    """Shortest-arc unit quaternions [n, 4] turning directions a onto b [n, 3] (a_len: |a|, b_len2:
    |b|², when known). Antiparallel pairs go through matrix_between's own choice, as the batched path."""
    dc = (a[:, :, None] * b[:, None, :]).reshape(-1, 9) @ _DOTCROSS                       # [a.b, a x b]
    bb = np.einsum("ij,ij->i", b, b) if b_len2 is None else b_len2
    ab = np.sqrt(bb * (a_len * a_len if a_len is not None else np.einsum("ij,ij->i", a, a)))
    dc[:, 0] += ab
    if not float((dc[:, 0] / ab).min()) >= 1e-9:    # antiparallel (or zero-length: NaN) somewhere
        from .quaternion import matrix_between
        return matrix_to_quat(matrix_between(a, b))
    return dc / np.sqrt(np.einsum("ij,ij->i", dc, dc))[:, None]


def _power_left(qs: list, rel: list, f2: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """qs · rel^f for two unit quaternions (plain floats, wxyz) and fractions f [k] (shortest arc
    first): [k, 4]. ``f2`` [k, 2] is f twice and ``phase`` [2] is (0, -pi/2), so that one cos gives
    the cos and sin of every half angle and one product the quaternions."""
    w, x, y, z = rel if rel[0] >= 0 else [-v for v in rel]
    s = math.sqrt(x * x + y * y + z * z)
    ax = [x / s, y / s, z / s] if s > 1e-15 else [0.0, 0.0, 0.0]
    a, b, c, d = qs
    # qs * (cos h, sin h · axis) = cos h · qs + sin h · (qs * (0, axis))
    u = [-b * ax[0] - c * ax[1] - d * ax[2], a * ax[0] + c * ax[2] - d * ax[1],
         a * ax[1] - b * ax[2] + d * ax[0], a * ax[2] + b * ax[1] - c * ax[0]]
    return np.cos(f2 * math.atan2(s, w) + phase) @ np.array([qs, u])


def _mul1(a: list, b: list) -> list:
    """a * b for two quaternions as plain floats (wxyz)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return [aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw]


def _v_between(a: list, b: list) -> list:
    """Shortest-arc unit quaternion (floats) turning direction a onto b (3 floats each); the
    antiparallel case through the batched helpers' own choice."""
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    ab = math.sqrt((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]))
    w = ab + dot
    if w < 1e-9 * ab:
        return _between(np.array([a]), np.array([b]))[0].tolist()
    q = [w, a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [x / n for x in q]


def _v_rotate(q: list, v: list) -> list:
    """v rotated by the unit quaternion q (floats)."""
    w, x, y, z = q
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + y * tz - z * ty, v[1] + w * ty + z * tx - x * tz, v[2] + w * tz + x * ty - y * tx]


def _leg_ik(hip: list, knee: list, ankle: list, target: list, l1: float, l2: float, pole: list):
    """foot_planting.two_bone_ik for one leg in plain floats: (thigh turn, shin turn) as unit
    quaternions, the knee kept in the leg's bend plane (``pole`` where the leg is straight)."""
    to = [target[i] - hip[i] for i in range(3)]
    dist = math.sqrt(to[0] ** 2 + to[1] ** 2 + to[2] ** 2)
    u = [x / max(dist, 1e-12) for x in to]
    d = min(max(dist, abs(l1 - l2) + 1e-6), l1 + l2 - 1e-6)
    cos_a = min(max((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1.0), 1.0)
    sin_a = math.sqrt(1.0 - cos_a * cos_a)
    k = [knee[i] - hip[i] for i in range(3)]
    ku = k[0] * u[0] + k[1] * u[1] + k[2] * u[2]
    perp = [k[i] - ku * u[i] for i in range(3)]
    if math.sqrt(perp[0] ** 2 + perp[1] ** 2 + perp[2] ** 2) > 1e-6 * l1:
        v = perp
    else:
        pu = pole[0] * u[0] + pole[1] * u[1] + pole[2] * u[2]
        v = [pole[i] - pu * u[i] for i in range(3)]
    vn = max(math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2), 1e-12)
    knee_new = [hip[i] + l1 * (cos_a * u[i] + sin_a * v[i] / vn) for i in range(3)]
    reach = [hip[i] + d * u[i] for i in range(3)]
    q1 = _v_between(k, [knee_new[i] - hip[i] for i in range(3)])
    shin = _v_rotate(q1, [ankle[i] - knee[i] for i in range(3)])   # ankle_after - knee_new
    q2 = _v_between(shin, [reach[i] - knee_new[i] for i in range(3)])
    return q1, q2


class LiveKernel:
    """The folded constants of one Retargeter and its one-frame ``run``."""

    def __init__(self, rt: "Retargeter", compiled: bool = True) -> None:
        """``compiled``: run frames through the numba kernels (:class:`CompiledFrame`; not with roll
        joints, which keep this numpy path), else through the numpy reference."""
        ch, J = rt.character, rt.character.n_joints
        self.rt = rt
        self.J = J
        mp = rt.mapping
        by = rt._by
        rot = [e for e in mp.joints if e.mode == "rotate" and e.rotation is not None]
        n = len(rot)
        a_q = [np.asarray(e.A, float) / np.linalg.norm(e.A) for e in rot]
        post_q = matrix_to_quat(rt._post) if n else np.zeros((0, 4))
        K = np.array([_left(a) @ _right(p) for a, p in zip(a_q, post_q)]).reshape(n, 4, 4)
        self.K = K
        R = len(rt.source.rotation_names)
        self.rot_src = rt._rot_src
        self.rot_joint = rt._rot_joint
        # source dependencies, level by level: qk[i] *= rot_ext[dep_idx[level, i]] (R: identity slot)
        deps = {i: d for i, d in rt._dep}
        depth = max((len(d) for d in deps.values()), default=0)
        self.dep_idx = np.full((depth, n), R, dtype=np.int64)
        for i, d in deps.items():
            self.dep_idx[:len(d), i] = d
        if depth == 0:   # gather and Eq 4.1 in one product
            big = np.zeros((4 * R, 4 * n))
            for i in range(n):
                big[4 * self.rot_src[i]:4 * self.rot_src[i] + 4, 4 * i:4 * i + 4] += K[i].T
            self.K_big = big
        # bone following
        self.follow_m = rt._follow_m
        self.follow_forms = _ROT @ rt._follow_bone[:, None, :, None] if len(rt._follow_m) else None
        if self.follow_forms is not None:
            self.follow_forms = self.follow_forms[..., 0]                                   # [nf, 16, 3]
            self.follow_len = np.linalg.norm(rt._follow_bone, axis=1)
            P = len(rt.source.point_names)
            nf = len(rt._follow_m)
            w = np.zeros((3 * P, 3 * nf))   # want = A (p_b - p_a), flat
            for i in range(nf):
                A = rt._A[rt._follow_m[i]]
                w[3 * rt._follow_b[i]:3 * rt._follow_b[i] + 3, 3 * i:3 * i + 3] += A.T
                w[3 * rt._follow_a[i]:3 * rt._follow_a[i] + 3, 3 * i:3 * i + 3] -= A.T
            self.follow_w = w
        # spread chains
        self.chains = []
        for c in rt._chains:
            d = dict(start=c["start"], end=c["end"], joints=c["joints"], frac=c["frac"], path=c["path"],
                     f2=np.repeat(np.asarray(c["frac"], float)[:, None], 2, axis=1),
                     iters=1 if c["endpt"] == c["end"] else 4,
                     correct=c["end_src"] >= 0 and c["pivot_src"] >= 0 and bool(np.isfinite(c["ratio"])),
                     end_src=c["end_src"], pivot_src=c["pivot_src"], A=c["ratio"] * c["A"])
            if d["correct"]:
                d["forms"] = (_ROT @ c["offsets"][:, None, :, None])[..., 0]
            self.chains.append(d)
        # aims (vectorised over the aim joints: each hangs from a joint not aimed itself)
        self.aims = None
        if rt._aims:
            par = np.array([ch.parents[a[0]] for a in rt._aims])
            pre = rt._src_pre[par]
            pre = np.where(pre < 0, pre + J, pre)   # the batched path's index, Python's negative wrap included
            self.aims = dict(joint=rt._aim_joint, pre=pre,
                             forms=(_ROT @ np.array([a[1] for a in rt._aims])[:, None, :, None])[..., 0],
                             frm=np.array([a[2] for a in rt._aims]), to=np.array([a[3] for a in rt._aims]),
                             A=np.array([a[4] for a in rt._aims]))
        # inheritance and rest orientation: W[j] = Δ_ext[s_j] · rest_world_q[j] (identity slot J)
        src = np.where(rt._src_post < 0, J, rt._src_post)
        rw_q = matrix_to_quat(rt._rest_world)
        par = np.where(ch.parents < 0, J, ch.parents)
        self.par_ext = par
        # one product gives every W and every W[parent] (the root's parent: the identity slot)
        # laid out per joint as [W[parent] | W] (8 columns), the pair the last step multiplies
        g = np.zeros((4 * (J + 1), 8 * J))
        for j in range(J):
            g[4 * src[j]:4 * src[j] + 4, 8 * j + 4:8 * j + 8] += _right(rw_q[j]).T
            p = par[j]
            if p < J:
                g[4 * src[p]:4 * src[p] + 4, 8 * j:8 * j + 4] += _right(rw_q[p]).T
            else:
                g[4 * J:4 * J + 4, 8 * j:8 * j + 4] += np.eye(4)
        self.G = g
        self.delta0 = np.tile(_ID, (J + 1, 1))
        self.jq_good = np.full((1, J), QUALITY_GOOD, np.int8)
        self._seen = None                  # the state whose seen flags are all set
        from .retarget import RetargetResult   # here, not at import: retarget imports this module
        self.Result = RetargetResult
        # positions: bones R(W[parent]) · offset, summed over ancestors; root from the source root
        self.bone_forms = (_ROT @ ch.rest_offsets[:, None, :, None])[..., 0]                # [J, 16, 3]
        self.anc = rt._anc
        M = np.zeros((3, 3))
        M[:2] = rt.ratio * rt._root_A[:2]
        M[2, 2] = rt.ratio
        self.root_M = M
        big = np.zeros((3 * len(rt.source.point_names), 3))
        big[3 * rt._root_src:3 * rt._root_src + 3] = M.T       # the source root's gather folded in
        self.root_big = big
        self.root_c = np.array([0.0, 0.0, rt._h_c - rt.ratio * rt._h_s + rt.options.floor_z]) + rt._offset
        self.root_src = rt._root_src
        # the mid-hip rule (Retargeter._midhip_rule): root += R(W[root]) s
        self.root_j = int(rt._root)
        self.root_s = None if rt._root_s is None else [float(v) for v in rt._root_s]
        # foot planting: the joints each leg's thigh and shin turns carry
        self.legs = None
        if rt._legs is not None:
            L = rt._legs
            aff, which = [], []
            for i in range(2):
                thigh = np.flatnonzero(L["sub"][i] & ~L["below_knee"][i])
                shin = np.flatnonzero(L["sub"][i] & L["below_knee"][i])
                aff += [thigh, shin]
                which += [np.full(len(thigh), i), np.full(len(shin), 2 + i)]
            self.legs = dict(aff=np.concatenate(aff), which=np.concatenate(which),
                             idx=np.concatenate([L["hip"], L["knee"], L["ankle"]]),
                             toe=L["toe"] if (L["toe"] >= 0).all() else None,
                             l1=L["l1"].tolist(), l2=L["l2"].tolist(), rest_h=L["rest_h"].tolist(),
                             toe_h=L["toe_h"].tolist())
        # local rotations: rest_local⁻¹ · conj(W[parent]) · W as a bilinear form per joint
        rl_inv = matrix_to_quat(np.swapaxes(rt._rest_local_inv, -1, -2))   # rest_local, then conjugated
        rl_inv[:, 1:] *= -1.0
        self.local_forms = np.stack([(_HAM * _CONJ16) @ _left(rl_inv[j]).T for j in range(J)])  # [J, 16, 4]
        # both at once from W[parent] ⊗ [W[parent] | W] [J, 32]: the bone vector (3) and the local rotation (4)
        both = np.zeros((J, 4, 8, 7))
        both[:, :, :4, :3] = self.bone_forms.reshape(J, 4, 4, 3)
        both[:, :, 4:, 3:] = self.local_forms.reshape(J, 4, 4, 4)
        self.both_forms = both.reshape(J, 32, 7)
        self.compiled = CompiledFrame(self) if compiled and not rt._rolls else None

    def release_state(self) -> None:
        """Before a batched call on the same retargeter: the compiled path's plants back in its state."""
        if self.compiled is not None:
            self.compiled.release_state()

    def _quat_in(self, q: np.ndarray) -> np.ndarray:
        """Δ [n, 4] of the rotate joints from the held unit source rotations [R, 4]."""
        if self.dep_idx.shape[0] == 0:
            return (q.reshape(-1) @ self.K_big).reshape(-1, 4)
        q_ext = np.concatenate([q, _ID[None]])
        qk = q[self.rot_src]
        for level in self.dep_idx:          # the few dependency levels, vectorised over joints
            qk = _mul(qk, q_ext[level])
        return np.einsum("nml,nl->nm", self.K, qk)

    def run(self, pts, pok, rot, rok, t):
        """One frame: points [P, 3], rotations [R, 4] (None: from the points), masks; returns the
        batched path's RetargetResult with F = 1 (compiled when it can be, else :meth:`run_numpy`)."""
        if self.compiled is not None:
            return self.compiled.run(pts, pok, rot, rok, t)
        return self.run_numpy(pts, pok, rot, rok, t)

    def run_numpy(self, pts, pok, rot, rok, t):
        """:meth:`run` in numpy (the reference of the compiled path)."""
        rt = self.rt
        st = rt._state
        # validity: one reduction each in the usual all-good case (NaN and inf make the sum non-finite)
        all_good = math.isfinite(pts.sum()) and (pok is None or bool(pok.all()))
        if not all_good:
            fin = np.isfinite(pts).all(-1)
            pok = fin if pok is None else (pok & fin)
        if rot is None:
            if rt._plan is None:
                raise ValueError("this source has rotations: pass them")
            rot = rotations_from_points_frame(rt._plan, pts if all_good else np.where(pok[:, None], pts, np.nan))
            nr = np.sqrt(np.einsum("ij,ij->i", rot, rot))
            rok = None
            if not math.isfinite(rot.sum()):
                rok = np.isfinite(rot).all(-1)
                all_good = False
        else:
            n2 = np.square(rot) @ _ONES4
            nr = np.sqrt(n2)
            # |n - 1| < 1e-3 for every rotation, from the extremes of n² (NaN fails both)
            if not (_N2_LO < float(n2.min()) and float(n2.max()) < _N2_HI and (rok is None or bool(rok.all()))):
                dev = np.abs(nr - 1.0) < 1e-3
                rok = dev if rok is None else (rok & dev)
                all_good = False
        if all_good:
            st.rot, st.pts = rot.copy(), pts.copy()
            if self._seen is not st:       # seen flags only grow: set once per state
                st.rot_seen[:] = True
                st.pts_seen[:] = True
                self._seen = st
        else:
            if pok is None:
                pok = np.ones(len(pts), bool)
            if rok is None:
                rok = np.ones(len(rot), bool)
            rot = np.where(rok[:, None], rot, st.rot)
            pts = np.where(pok[:, None], pts, st.pts)
            nr = np.sqrt(np.einsum("ij,ij->i", rot, rot))
            rq = np.where(rok, QUALITY_GOOD, np.where(st.rot_seen, 1, 0)).astype(np.int8)
            pq = np.where(pok, QUALITY_GOOD, np.where(st.pts_seen, 1, 0)).astype(np.int8)
            st.rot, st.pts = rot.copy(), pts.copy()
            st.rot_seen |= rok
            st.pts_seen |= pok
        J = self.J
        pflat = pts.reshape(-1)
        # 1. rotate joints (Eq 4.1), bones following the source bones
        dq = self._quat_in(rot / nr[:, None])
        if self.follow_forms is not None:
            sub = dq[self.follow_m]
            have = _rotate_const(sub, self.follow_forms)
            want = (pflat @ self.follow_w).reshape(-1, 3)
            wn2 = np.square(want) @ _ONES3
            if not float(wn2.min()) > 1e-18:     # |want| > 1e-9 m, as the batched path
                ok = np.sqrt(wn2) > 1e-9
                want = np.where(ok[:, None], want, have)
                wn2 = np.einsum("ij,ij->i", want, want)
            dq[self.follow_m] = _mul(_between(have, want, self.follow_len, wn2), sub)
        D = self.delta0.copy()
        D[self.rot_joint] = dq
        # 2. spread chains (per chain, not per joint: the slerp of two quaternions in plain floats)
        for c in self.chains:
            qs, qe = D[c["start"]].tolist(), D[c["end"]].tolist()
            rel = _mul1([qs[0], -qs[1], -qs[2], -qs[3]], qe)
            D[c["joints"]] = _power_left(qs, rel, c["f2"], _PHASE)
            if c["correct"]:
                target = c["A"] @ (pts[c["end_src"]] - pts[c["pivot_src"]])
                path, js = c["path"], c["joints"]
                for _ in range(c["iters"]):
                    vec = _rotate_const(D[path], c["forms"]).sum(0)
                    corr = _between(vec[None], target[None])
                    D[js] = D[js] @ _left(corr[0]).T
        # 3./4. aims from the parent-carried rest bone
        if self.aims is not None:
            a = self.aims
            dp = D[a["pre"]]
            carried = _rotate_const(dp, a["forms"])
            want = (a["A"] @ (pts[a["to"]] - pts[a["frm"]])[:, :, None])[..., 0]
            D[a["joint"]] = _mul(_between(carried, want), dp)
        # world orientations (inherited, then the rest orientation) and the parents'
        WW = (D.reshape(-1) @ self.G).reshape(J, 8)
        Wp, W = WW[:, :4], WW[:, 4:]
        if rt._rolls:   # rare (roll joints): the batched path's own code, on matrices
            Wm = quat_to_matrix(W)[None]
            for r, o, f, upper in rt._rolls:
                Wm = rt._apply_roll(Wm, r, o, f, upper)
            W = matrix_to_quat(Wm[0])
            Wp = np.concatenate([W, _ID[None]])[self.par_ext]
            WW = np.concatenate([Wp, W], axis=1)
        # 5./6. root, positions and local rotations (w >= 0, as matrix_to_quat gives them)
        root = pflat @ self.root_big + self.root_c
        if self.root_s is not None:      # in plain floats: one numpy call, not three
            root += _v_rotate(W[self.root_j].tolist(), self.root_s)
        bl = ((Wp[:, :, None] * WW[:, None, :]).reshape(J, 1, 32) @ self.both_forms)[:, 0]
        pos = root + self.anc @ bl[:, :3]
        local = bl[:, 3:]
        contact = np.zeros((1, 2), bool)
        if self.legs is not None:
            W2, Wp, pos, contact = self._plant(W, Wp, pos, root, 0.0 if t is None else (t if isinstance(t, float) else float(np.asarray(t).reshape(-1)[0])))
            if W2 is not W:   # the legs moved: their local rotations anew
                local = ((Wp[:, :, None] * W2[:, None, :]).reshape(J, 1, 16) @ self.local_forms)[:, 0]
        local = local * np.copysign(1.0, local[:, :1])
        jq = self.jq_good.copy() if all_good else rt._quality(rq[None], pq[None])
        return self.Result(local[None], root[None], pos[None], jq, contact)

    def _plant(self, W, Wp, pos, root, t: float):
        """Retargeter._plant for one frame: contact and targets (foot_planting.plant_one), two-bone
        IK per leg in plain floats, the thigh and shin turns applied to the joints they carry."""
        rt, L, opt = self.rt, self.legs, self.rt.options
        hka = pos[L["idx"]].tolist()                      # hips, knees, ankles: l, r
        ankle = hka[4:6]
        toe_lift = None
        if L["toe"] is not None:
            tz = pos[L["toe"], 2].tolist()
            toe_lift = [opt.floor_z + L["toe_h"][i] - tz[i] for i in (0, 1)]
        k = max(rt.ratio, 1e-3)
        target, contact = plant_one(ankle, L["rest_h"], t, rt._state.plant, floor_z=opt.floor_z,
                                    height_m=opt.contact_height_m * k, speed_mps=opt.contact_speed_mps * k,
                                    release_s=opt.release_s, toe_lift=toe_lift)
        contact = np.array([contact])
        gap = [max(abs(target[i][c] - ankle[i][c]) for c in range(3)) for i in (0, 1)]
        need = [g >= 1e-12 for g in gap]                 # NaN gaps (no data) need nothing
        if not (need[0] or need[1]):
            return W, Wp, pos, contact
        hq = W[rt._legs["hip"]].tolist()
        turns = [[1.0, 0.0, 0.0, 0.0]] * 4               # thigh l, thigh r, shin l, shin r
        for i in (0, 1):   # the two legs
            if not need[i]:
                continue
            w, x, y, z = hq[i]
            pole = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]   # the thigh's forward axis
            q1, q2 = _leg_ik(hka[i], hka[2 + i], ankle[i], target[i], L["l1"][i], L["l2"][i], pole)
            turns[i] = q1
            turns[2 + i] = _mul1(q2, q1)
        aff = L["aff"]
        W = W.copy()
        W[aff] = _mul(np.array(turns)[L["which"]], W[aff])
        Wp = np.concatenate([W, _ID[None]])[self.par_ext]
        pos = root + self.anc @ _rotate_const(Wp, self.bone_forms)
        return W, Wp, pos, contact


def _pack_plant(plant, ps: np.ndarray, cap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A PlantState into the compiled path's arrays (retarget_kernels' layout): fills ``ps`` [13],
    returns (times [cap'], xy [cap', 4], count [1]) with cap' >= cap and room for one more sample."""
    ps[0:2] = plant.planted
    ps[2:6] = np.asarray(plant.anchor, float).reshape(4)
    ps[6:10] = np.asarray(plant.offset, float).reshape(4)
    ps[10] = plant.last_t
    ps[11:13] = plant.low
    n = len(plant.history_t)
    cap = max(cap, 2 * (n + 1))
    ht, hxy = np.zeros(cap), np.zeros((cap, 4))
    if n:
        ht[:n] = plant.history_t
        hxy[:n] = np.asarray(plant.history_xy, float).reshape(n, 4)
    return ht, hxy, np.array([n], np.int64)


def _unpack_plant(plant, ps: np.ndarray, ht: np.ndarray, hxy: np.ndarray, hn: np.ndarray) -> None:
    """The compiled path's plant arrays back into the PlantState the batched path reads."""
    n = int(hn[0])
    plant.planted = ps[0:2] != 0.0
    plant.anchor = ps[2:6].reshape(2, 2).copy()
    plant.offset = ps[6:10].reshape(2, 2).copy()
    plant.last_t = float(ps[10])
    plant.low = ps[11:13].copy()
    plant.history_t = ht[:n].tolist()
    plant.history_xy = list(hxy[:n].reshape(n, 2, 2).copy())


class CompiledFrame:
    """The one-frame path as numba kernels (retarget_kernels): the LiveKernel's constants as plain
    arrays, scratch preallocated; ``run`` gives LiveKernel.run's result (to rounding, tested)."""

    def __init__(self, lk: LiveKernel) -> None:
        from . import retarget_kernels as rk
        self.k = rk
        rt, ch, J = lk.rt, lk.rt.character, lk.J
        self.lk, self.rt, self.J = lk, rt, J
        i64 = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.int64).reshape(-1))   # noqa: E731
        f64 = lambda a, *shape: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(shape))  # noqa: E731
        n = len(lk.rot_src)
        self.rot_src, self.rot_joint = i64(lk.rot_src), i64(lk.rot_joint)
        self.dep_idx = np.ascontiguousarray(lk.dep_idx, dtype=np.int64).reshape(-1, n)
        self.K = f64(lk.K, n, 4, 4)
        nf = len(rt._follow_m)
        self.f_m, self.f_a, self.f_b = i64(rt._follow_m), i64(rt._follow_a), i64(rt._follow_b)
        self.f_bone = f64(rt._follow_bone, nf, 3)
        self.f_A = f64(rt._A[rt._follow_m] if nf else np.zeros((0, 3, 3)), nf, 3, 3)
        cs = lk.chains
        self.c_start, self.c_end = i64([c["start"] for c in cs]), i64([c["end"] for c in cs])
        self.c_jptr = i64(np.cumsum([0] + [len(c["joints"]) for c in cs]))
        self.c_joints = i64(np.concatenate([c["joints"] for c in cs]) if cs else [])
        self.c_frac = f64(np.concatenate([c["frac"] for c in cs]) if cs else [], -1)
        self.c_iters = i64([c["iters"] for c in cs])
        self.c_correct = np.array([c["correct"] for c in cs], dtype=np.bool_)
        self.c_end_src, self.c_pivot_src = i64([c["end_src"] for c in cs]), i64([c["pivot_src"] for c in cs])
        self.c_A = f64([c["A"] if c["correct"] else np.zeros((3, 3)) for c in cs] if cs else [], len(cs), 3, 3)
        paths = [c["path"] if c["correct"] else np.zeros(0, np.int64) for c in cs]
        self.c_pptr = i64(np.cumsum([0] + [len(p) for p in paths]))
        self.c_path = i64(np.concatenate(paths) if paths else [])
        offs = [c["offsets"] if lc["correct"] else np.zeros((0, 3)) for c, lc in zip(rt._chains, cs)]
        self.c_off = f64(np.concatenate(offs) if offs else [], -1, 3)
        a = lk.aims
        na = 0 if a is None else len(a["joint"])
        self.a_joint, self.a_pre = i64(a["joint"] if na else []), i64(a["pre"] if na else [])
        self.a_bone = f64([x[1] for x in rt._aims] if na else [], na, 3)
        self.a_frm, self.a_to = i64(a["frm"] if na else []), i64(a["to"] if na else [])
        self.a_A = f64(a["A"] if na else [], na, 3, 3)
        self.src_ext = i64(np.where(rt._src_post < 0, J, rt._src_post))
        self.rw_q = f64(matrix_to_quat(rt._rest_world), J, 4)
        self.parents = i64(ch.parents)
        order, seen = [], set()
        while len(order) < J:   # parents first (the character has no cycle: checked when loaded)
            for j in range(J):
                if j not in seen and (ch.parents[j] < 0 or ch.parents[j] in seen):
                    order.append(j)
                    seen.add(j)
        self.order = i64(order)
        self.offsets = f64(ch.rest_offsets, J, 3)
        rl = matrix_to_quat(np.swapaxes(rt._rest_local_inv, -1, -2))   # rest_local, conjugated
        rl[:, 1:] *= -1.0
        self.rl_inv = f64(rl, J, 4)
        self.root_src = int(rt._root_src)
        self.root_M, self.root_c = f64(lk.root_M, 3, 3), f64(lk.root_c, 3)
        P, R = len(rt.source.point_names), len(rt.source.rotation_names)
        self.ones_p, self.ones_r = np.ones(P, np.bool_), np.ones(R, np.bool_)
        self.check_norm = rt._plan is None
        # source qualities of the last frame (read when a frame was not all good); float scratch: self.wk
        self.pq, self.rq = np.empty(P, np.int8), np.empty(R, np.int8)
        self.jq_good = lk.jq_good
        # an optical actor's joints (the source's points but the pelvis, last) and the hips whose
        # mean the pelvis is: the actor frame lays them out in the kernel (run_actor)
        self.hips = None
        if rt.source.kind == "optical":
            self.hips = i64(pelvis_hips(rt.source.point_names[:-1]))
        self.actor_shapes = ((P - 1, 3), (P - 1,), (R, 4), (R,))
        chk = rt._checks
        self.Result = lk.Result
        self.legs = None
        if lk.legs is not None:
            L, opt = rt._legs, rt.options
            k = max(rt.ratio, 1e-3)
            self.legs = (i64(L["hip"]), i64(L["knee"]), i64(L["ankle"]), i64(np.maximum(L["toe"], 0)),
                         bool((L["toe"] >= 0).all()), f64(L["l1"], 2), f64(L["l2"], 2), f64(L["rest_h"], 2),
                         f64(np.nan_to_num(L["toe_h"]), 2), i64(lk.legs["aff"]), i64(lk.legs["which"]))
            self.plant_params = (float(opt.floor_z), float(opt.contact_height_m * k), float(opt.contact_speed_mps * k),
                                 float(opt.release_s), 0.05)   # plant_one's window_s
            self.ps = np.zeros(13)
            self.ht, self.hxy, self.hn = np.zeros(64), np.zeros((64, 4)), np.zeros(1, np.int64)
        self._plant_for = None      # the retargeter state whose plants the arrays above hold
        self._out_checked = None    # the last ``out`` of run_actor found to fit (see _check_out)
        if self.legs is None:       # the frame kernel's plant arguments, unused
            self.ps, self.ht, self.hxy, self.hn = np.zeros(13), np.zeros(2), np.zeros((2, 4)), np.zeros(1, np.int64)
        lg = self.legs or (np.zeros(0, np.int64),) * 4 + (False,) + (np.zeros(0),) * 4 + (np.zeros(0, np.int64),) * 2
        ints = dict(rot_src=self.rot_src, dep_idx=self.dep_idx, rot_joint=self.rot_joint, f_m=self.f_m, f_a=self.f_a,
                    f_b=self.f_b, c_start=self.c_start, c_end=self.c_end, c_jptr=self.c_jptr, c_joints=self.c_joints,
                    c_iters=self.c_iters, c_correct=self.c_correct, c_end_src=self.c_end_src,
                    c_pivot_src=self.c_pivot_src, c_pptr=self.c_pptr, c_path=self.c_path, a_joint=self.a_joint,
                    a_pre=self.a_pre, a_frm=self.a_frm, a_to=self.a_to, src_ext=self.src_ext, parents=self.parents,
                    order=self.order, scalars=[self.root_src, self.legs is not None, bool(lg[4]), self.check_norm,
                                                     lk.root_j],
                    hip=lg[0], knee=lg[1], ankle=lg[2], toe=lg[3], aff=lg[9], which=lg[10],
                    hips=self.hips if self.hips is not None else np.zeros(0, np.int64), b_joint=chk.joint,
                    b_child=chk.child, b_a=chk.a, b_b=chk.b)
        floats = dict(K=self.K, f_bone=self.f_bone, f_A=self.f_A, c_frac=self.c_frac, c_A=self.c_A, c_off=self.c_off,
                      a_bone=self.a_bone, a_A=self.a_A, rw_q=self.rw_q, offsets=self.offsets, rl_inv=self.rl_inv,
                      root_M=self.root_M, root_c=self.root_c,
                      root_s=np.zeros(3) if rt._root_s is None else rt._root_s, l1=lg[5], l2=lg[6], rest_h=lg[7], toe_h=lg[8],
                      plant=self.plant_params if self.legs is not None else np.zeros(5), b_A=chk.A, b_cos=chk.cos_limit)
        work = dict(qn=4 * R, qk=4 * max(n, 1), dq=4 * max(n, 1), ap=4 * max(na, 1), D=4 * (J + 1), W=4 * J, tmp=8,
                    ank=6, toe_z=2, target=6, speed=2, turns=16, pin=3 * P)
        self.ci, self.cf, self.wk = rk.pack(ints, floats, work)
        self.bk = np.zeros(P + R, np.bool_)   # the actor frame's point and rotation masks

    def release_state(self) -> None:
        """Hand the plants back to the state's PlantState (the batched path is about to read it)."""
        st = self._plant_for
        if st is not None:
            _unpack_plant(st.plant, self.ps, self.ht, self.hxy, self.hn)
            self._plant_for = None

    def _plants_ready(self, st, t) -> float:
        """The plant arrays in step with the state ``st`` (a fresh one after reset, or one the batched
        path moved on), the speed window room for one more frame; returns the time as a float."""
        if self.legs is None:
            return 0.0
        if self._plant_for is not st:
            self.ht, self.hxy, self.hn = _pack_plant(st.plant, self.ps, len(self.ht))
            self._plant_for = st
        if self.hn[0] + 1 >= len(self.ht):  # a faster stream than the window held so far
            self.ht = np.concatenate([self.ht, np.zeros(len(self.ht))])
            self.hxy = np.concatenate([self.hxy, np.zeros((len(self.hxy), 4))])
        return 0.0 if t is None else (t if isinstance(t, float) else float(np.asarray(t).reshape(-1)[0]))

    def buffers(self):
        """A result of one frame ([1, ...] arrays) for :meth:`run_actor` to write into (``out``)."""
        J = self.J
        return self.Result(np.empty((1, J, 4)), np.empty((1, 3)), np.empty((1, J, 3)), np.empty((1, J), np.int8),
                           np.empty((1, 2), np.bool_))

    def _check_out(self, out) -> None:
        """``out`` has :meth:`buffers`' shapes and dtypes, C-contiguous and writable (ValueError)."""
        for a, want in zip(vars(out).values(), vars(self.buffers()).values()):
            if not (isinstance(a, np.ndarray) and a.shape == want.shape and a.dtype == want.dtype
                    and a.flags.c_contiguous and a.flags.writeable):
                raise ValueError(f"out: the buffers of this character ({self.J} joints) come from buffers(); an "
                                 f"array here is {getattr(a, 'shape', type(a).__name__)} where {want.shape} "
                                 f"{want.dtype} is wanted")
        self._out_checked = out

    def run_actor(self, jp, jq, rot, lq, t, out=None):
        """One solved-actor frame (optical source) at time ``t`` (s, a float): joints [J, 3], quality [J],
        limb rotations [R, 4], quality [R] (int8), C-contiguous as a message holds them, all read-only (decoded) or all
        writable (the two compiled variants); :meth:`run` of OpticalFrames' points and the limbs of
        quality >= 1, with the bone-follow flags, in one kernel call. ``out`` (from :meth:`buffers`):
        written and returned instead of a new result (a caller that hands the arrays on before the
        next frame, as the node does, allocates nothing per frame)."""
        if (jp.shape, jq.shape, rot.shape, lq.shape) != self.actor_shapes:   # the kernel does not check bounds
            raise ValueError(f"an actor frame of this source wants joints {self.actor_shapes[0]}, quality "
                             f"{self.actor_shapes[1]}, limbs {self.actor_shapes[2]}, {self.actor_shapes[3]}")
        k, rt = self.k, self.rt
        st = rt._state
        if self._plant_for is not st:   # (after that, the kernel's return value says when the window needs room)
            self._plants_ready(st, t)
        if out is None:
            out = self.buffers()
        elif out is not self._out_checked:   # the kernel writes without bounds checks: once per buffer set
            self._check_out(out)
        local, root, pos, jq_out, contact = (out.local_rotations, out.root_positions, out.joint_positions,
                                             out.joint_quality, out.contact)
        done = k.retarget_actor_frame(jp, jq, rot, lq, t, st.pts, st.rot, st.pts_seen, st.rot_seen, self.pq, self.rq,
                                      self.ps, self.ht, self.hxy, self.hn, self.ci, self.cf, self.wk, self.bk,
                                      root, pos, local, contact, jq_out)
        if done & 2 and self.legs is not None:
            self._plants_ready(st, t)
        if not done & 1:
            jq_out[:] = rt._quality(self.rq[None], self.pq[None])   # something missing: held, flagged below
            c = rt._checks
            if c.joint.size:
                k.flag_unfollowed(pos[0], st.pts, c.joint, c.child, c.a, c.b, c.A, c.cos_limit, jq_out[0])
        return out

    def run(self, pts, pok, rot, rok, t):
        """One frame, as LiveKernel.run: points [P, 3], rotations [R, 4] or None, masks or None."""
        k, rt = self.k, self.rt
        st = rt._state
        # writable C-contiguous inputs only: a strided or read-only view (a decoded message) would
        # compile (and cache) another variant of the kernel, seconds in a running node
        if not (pts.flags.c_contiguous and pts.flags.writeable):
            pts = np.array(pts, order="C")
        if pok is None:
            pok = self.ones_p
        elif not (pok.flags.c_contiguous and pok.flags.writeable):
            pok = np.array(pok, order="C")
        if rot is None:
            if rt._plan is None:
                raise ValueError("this source has rotations: pass them")
            fin = np.isfinite(pts).all(-1) & pok
            rot = rotations_from_points_frame(rt._plan, np.where(fin[:, None], pts, np.nan))
            rok = self.ones_r
        elif not (rot.flags.c_contiguous and rot.flags.writeable):
            rot = np.array(rot, order="C")
        if rok is None:
            rok = self.ones_r
        elif not (rok.flags.c_contiguous and rok.flags.writeable):
            rok = np.array(rok, order="C")
        tf = self._plants_ready(st, t)
        J = self.J
        root = np.empty((1, 3))
        pos = np.empty((1, J, 3))
        local = np.empty((1, J, 4))
        contact = np.empty((1, 2), np.bool_)
        good = k.retarget_frame(pts, pok, rot, rok, tf, st.pts, st.rot, st.pts_seen, st.rot_seen, self.pq, self.rq,
                                self.ps, self.ht, self.hxy, self.hn, self.ci, self.cf, self.wk,
                                root[0], pos[0], local[0], contact[0])
        jq = self.jq_good.copy() if good else rt._quality(self.rq[None], self.pq[None])
        return self.Result(local, root, pos, jq, contact)
