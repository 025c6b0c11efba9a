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
input is good (then every joint is good). The folding is :mod:`live_fold`, its algebra
:mod:`quat_forms`; :class:`CompiledFrame` runs the same frame through :mod:`kernels`.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from ..kinematics.quaternion import matrix_to_quat, quat_multiply_rows, quat_to_matrix
from .batched import apply_roll, joint_quality
from .foot_planting import plant_one
from .live_fold import FoldedPlan
from .quat_forms import (ID, N2_HI, N2_LO, ONES3, ONES4, PHASE, between_rows, leg_ik, left_map, mul1,
                         power_left, rotate_const, v_rotate)
from .source import pelvis_hips, rotations_from_points_frame

if TYPE_CHECKING:
    from .retargeter import Retargeter

QUALITY_GOOD = 2


class LiveKernel(FoldedPlan):
    """One Retargeter's one-frame path: its plan folded (:class:`FoldedPlan`) and the frame's ``run``."""

    def __init__(self, rt: "Retargeter", compiled: bool = True) -> None:
        """``compiled``: run frames through the numba kernels (:class:`CompiledFrame`; not with roll
        joints, which keep this numpy path), else through the numpy reference."""
        super().__init__(rt)
        self._seen = None                  # the state whose seen flags are all set
        self.compiled = CompiledFrame(self) if compiled and not rt.plan.rolls else None

    def release_state(self) -> None:
        """Before a batched call on the same retargeter: the compiled path's plants back in its state."""
        if self.compiled is not None:
            self.compiled.release_state()

    def _quat_in(self, q: np.ndarray) -> np.ndarray:
        """Δ [n, 4] of the rotate joints from the held unit source rotations [R, 4]."""
        if self.dep_idx.shape[0] == 0:
            return (q.reshape(-1) @ self.K_big).reshape(-1, 4)
        q_ext = np.concatenate([q, ID[None]])
        qk = q[self.rot_src]
        for level in self.dep_idx:          # the few dependency levels, vectorised over joints
            qk = quat_multiply_rows(qk, q_ext[level])
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
        pts, rot, nr, all_good, rq, pq = self._held(pts, pok, rot, rok)
        J = self.J
        pflat = pts.reshape(-1)
        D = self._deltas(rot / nr[:, None], pts, pflat)
        # world orientations (inherited, then the rest orientation) and the parents'
        WW = (D.reshape(-1) @ self.G).reshape(J, 8)
        Wp, W = WW[:, :4], WW[:, 4:]
        if rt.plan.rolls:   # rare (roll joints): the batched path's own code, on matrices
            Wm = quat_to_matrix(W)[None]
            for r, o, f, upper in rt.plan.rolls:
                Wm = apply_roll(rt.character, Wm, r, o, f, upper)
            W = matrix_to_quat(Wm[0])
            Wp = np.concatenate([W, ID[None]])[self.par_ext]
            WW = np.concatenate([Wp, W], axis=1)
        # 5./6. root, positions and local rotations (w >= 0, as matrix_to_quat gives them)
        root = pflat @ self.root_big + self.root_c
        if self.root_s is not None:      # in plain floats: one numpy call, not three
            root += v_rotate(W[self.root_j].tolist(), self.root_s)
        bl = ((Wp[:, :, None] * WW[:, None, :]).reshape(J, 1, 32) @ self.both_forms)[:, 0]
        pos = root + self.anc @ bl[:, :3]
        local = bl[:, 3:]
        contact = np.zeros((1, 2), bool)
        if self.legs is not None:
            W2, Wp, pos, contact = self._plant(W, Wp, pos, root, 0.0 if t is None else (t if isinstance(t, float) else float(np.asarray(t).reshape(-1)[0])))
            if W2 is not W:   # the legs moved: their local rotations anew
                local = ((Wp[:, :, None] * W2[:, None, :]).reshape(J, 1, 16) @ self.local_forms)[:, 0]
        local = local * np.copysign(1.0, local[:, :1])
        jq = self.jq_good.copy() if all_good else joint_quality(rt.plan, rq[None], pq[None])
        return self.Result(local[None], root[None], pos[None], jq, contact)

    def _held(self, pts, pok, rot, rok):
        """This frame's source values with the missing ones held from the state (which is updated):
        (points [P, 3], rotations [R, 4], their norms [R], whether all were good, and, when not, the
        rotations' and points' quality [R], [P]; None when all were good)."""
        st = self.rt.state
        rq = pq = None
        # validity: one reduction each in the usual all-good case (NaN and inf make the sum non-finite)
        all_good = math.isfinite(pts.sum()) and (pok is None or bool(pok.all()))
        if not all_good:
            fin = np.isfinite(pts).all(-1)
            pok = fin if pok is None else (pok & fin)
        if rot is None:
            if self.rt.plan.point_plan is None:
                raise ValueError("this source has rotations: pass them")
            rot = rotations_from_points_frame(self.rt.plan.point_plan, pts if all_good else np.where(pok[:, None], pts, np.nan))
            nr = np.sqrt(np.einsum("ij,ij->i", rot, rot))
            rok = None
            if not math.isfinite(rot.sum()):
                rok = np.isfinite(rot).all(-1)
                all_good = False
        else:
            n2 = np.square(rot) @ ONES4
            nr = np.sqrt(n2)
            # |n - 1| < 1e-3 for every rotation, from the extremes of n² (NaN fails both)
            if not (N2_LO < float(n2.min()) and float(n2.max()) < N2_HI and (rok is None or bool(rok.all()))):
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
        return pts, rot, nr, all_good, rq, pq

    def _deltas(self, q, pts, pflat):
        """Δ [J + 1, 4] of every driven joint from the unit source rotations ``q`` [R, 4] and the
        points [P, 3] (``pflat`` [3P]): Eq 4.1 with bone following, spread chains, aims (identity slot J)."""
        # 1. rotate joints (Eq 4.1), bones following the source bones
        dq = self._quat_in(q)
        if self.follow_forms is not None:
            sub = dq[self.follow_m]
            have = rotate_const(sub, self.follow_forms)
            want = (pflat @ self.follow_w).reshape(-1, 3)
            wn2 = np.square(want) @ ONES3
            if not float(wn2.min()) > 1e-18:     # |want| > 1e-9 m, as the batched path
                ok = np.sqrt(wn2) > 1e-9
                want = np.where(ok[:, None], want, have)
                wn2 = np.einsum("ij,ij->i", want, want)
            dq[self.follow_m] = quat_multiply_rows(between_rows(have, want, self.follow_len, wn2), sub)
        D = self.delta0.copy()
        D[self.rot_joint] = dq
        # 2. spread chains (per chain, not per joint: the slerp of two quaternions in plain floats)
        for c in self.chains:
            qs, qe = D[c["start"]].tolist(), D[c["end"]].tolist()
            rel = mul1([qs[0], -qs[1], -qs[2], -qs[3]], qe)
            D[c["joints"]] = power_left(qs, rel, c["f2"], PHASE)
            if c["correct"]:
                target = c["A"] @ (pts[c["end_src"]] - pts[c["pivot_src"]])
                path, js = c["path"], c["joints"]
                for _ in range(c["iters"]):
                    vec = rotate_const(D[path], c["forms"]).sum(0)
                    corr = between_rows(vec[None], target[None])
                    D[js] = D[js] @ left_map(corr[0]).T
        # 3./4. aims from the parent-carried rest bone
        if self.aims is not None:
            a = self.aims
            dp = D[a["pre"]]
            carried = rotate_const(dp, a["forms"])
            want = (a["A"] @ (pts[a["to"]] - pts[a["frm"]])[:, :, None])[..., 0]
            D[a["joint"]] = quat_multiply_rows(between_rows(carried, want), dp)
        return D

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
        target, contact = plant_one(ankle, L["rest_h"], t, rt.state.plant, floor_z=opt.floor_z,
                                    height_m=opt.contact_height_m * k, speed_mps=opt.contact_speed_mps * k,
                                    release_s=opt.release_s, toe_lift=toe_lift)
        contact = np.array([contact])
        gap = [max(abs(target[i][c] - ankle[i][c]) for c in range(3)) for i in (0, 1)]
        need = [g >= 1e-12 for g in gap]                 # NaN gaps (no data) need nothing
        if not (need[0] or need[1]):
            return W, Wp, pos, contact
        hq = W[rt.plan.legs["hip"]].tolist()
        turns = [[1.0, 0.0, 0.0, 0.0]] * 4               # thigh l, thigh r, shin l, shin r
        for i in (0, 1):   # the two legs
            if not need[i]:
                continue
            w, x, y, z = hq[i]
            pole = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]   # the thigh's forward axis
            q1, q2 = leg_ik(hka[i], hka[2 + i], ankle[i], target[i], L["l1"][i], L["l2"][i], pole)
            turns[i] = q1
            turns[2 + i] = mul1(q2, q1)
        aff = L["aff"]
        W = W.copy()
        W[aff] = quat_multiply_rows(np.array(turns)[L["which"]], W[aff])
        Wp = np.concatenate([W, ID[None]])[self.par_ext]
        pos = root + self.anc @ rotate_const(Wp, self.bone_forms)
        return W, Wp, pos, contact


def _pack_plant(plant, ps: np.ndarray, cap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A PlantState into the compiled path's arrays (kernels' layout): fills ``ps`` [13],
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
    """The one-frame path as numba kernels (kernels): the LiveKernel's constants as plain
    arrays, scratch preallocated; ``run`` gives LiveKernel.run's result (to rounding, tested)."""

    def __init__(self, lk: LiveKernel) -> None:
        from . import kernels as rk
        self.k = rk
        rt, ch, J = lk.rt, lk.rt.character, lk.J
        self.lk, self.rt, self.J = lk, rt, J
        i64 = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.int64).reshape(-1))   # noqa: E731
        f64 = lambda a, *shape: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(shape))  # noqa: E731
        n = len(lk.rot_src)
        self.rot_src, self.rot_joint = i64(lk.rot_src), i64(lk.rot_joint)
        self.dep_idx = np.ascontiguousarray(lk.dep_idx, dtype=np.int64).reshape(-1, n)
        self.K = f64(lk.K, n, 4, 4)
        nf = len(rt.plan.follow_m)
        self.f_m, self.f_a, self.f_b = i64(rt.plan.follow_m), i64(rt.plan.follow_a), i64(rt.plan.follow_b)
        self.f_bone = f64(rt.plan.follow_bone, nf, 3)
        self.f_A = f64(rt.plan.A[rt.plan.follow_m] if nf else np.zeros((0, 3, 3)), nf, 3, 3)
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
        offs = [c["offsets"] if lc["correct"] else np.zeros((0, 3)) for c, lc in zip(rt.plan.chains, cs)]
        self.c_off = f64(np.concatenate(offs) if offs else [], -1, 3)
        a = lk.aims
        na = 0 if a is None else len(a["joint"])
        self.a_joint, self.a_pre = i64(a["joint"] if na else []), i64(a["pre"] if na else [])
        self.a_bone = f64([x[1] for x in rt.plan.aims] if na else [], na, 3)
        self.a_frm, self.a_to = i64(a["frm"] if na else []), i64(a["to"] if na else [])
        self.a_A = f64(a["A"] if na else [], na, 3, 3)
        self.src_ext = i64(np.where(rt.plan.src_post < 0, J, rt.plan.src_post))
        self.rw_q = f64(matrix_to_quat(rt.plan.rest_world), J, 4)
        self.parents = i64(ch.parents)
        order, seen = [], set()
        while len(order) < J:   # parents first (the character has no cycle: checked when loaded)
            for j in range(J):
                if j not in seen and (ch.parents[j] < 0 or ch.parents[j] in seen):
                    order.append(j)
                    seen.add(j)
        self.order = i64(order)
        self.offsets = f64(ch.rest_offsets, J, 3)
        rl = matrix_to_quat(np.swapaxes(rt.plan.rest_local_inv, -1, -2))   # rest_local, conjugated
        rl[:, 1:] *= -1.0
        self.rl_inv = f64(rl, J, 4)
        self.root_src = int(rt.plan.root_src)
        self.root_M, self.root_c = f64(lk.root_M, 3, 3), f64(lk.root_c, 3)
        P, R = len(rt.source.point_names), len(rt.source.rotation_names)
        self.ones_p, self.ones_r = np.ones(P, np.bool_), np.ones(R, np.bool_)
        self.check_norm = rt.plan.point_plan is None
        # source qualities of the last frame (read when a frame was not all good); float scratch: self.wk
        self.pq, self.rq = np.empty(P, np.int8), np.empty(R, np.int8)
        self.jq_good = lk.jq_good
        # an optical actor's joints (the source's points but the pelvis, last) and the hips whose
        # mean the pelvis is: the actor frame lays them out in the kernel (run_actor)
        self.hips = None
        if rt.source.kind == "optical":
            self.hips = i64(pelvis_hips(rt.source.point_names[:-1]))
        self.actor_shapes = ((P - 1, 3), (P - 1,), (R, 4), (R,))
        chk = rt.plan.checks
        self.Result = lk.Result
        self.legs = None
        if lk.legs is not None:
            L, opt = rt.plan.legs, rt.options
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
                      root_s=np.zeros(3) if rt.plan.root_s is None else rt.plan.root_s, l1=lg[5], l2=lg[6], rest_h=lg[7], toe_h=lg[8],
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
        st = rt.state
        if self._plant_for is not st:   # (after that, the kernel's return value says when the window needs room)
            self._plants_ready(st, t)
        if out is None:
            out = self.buffers()
        elif out is not self._out_checked:   # the kernel writes without bounds checks: once per buffer set
            self._check_out(out)
        local, root, pos, jq_out, contact = (out.local_rotations, out.root_positions, out.joint_positions,
                                             out.joint_quality, out.contact)
        done = k.retarget_actor_frame(jp, jq, rot, lq, t, (st.pts, st.rot, st.pts_seen, st.rot_seen, self.pq, self.rq),
                                      (self.ps, self.ht, self.hxy, self.hn), (self.ci, self.cf, self.wk, self.bk),
                                      (root, pos, local, contact, jq_out))
        if done & 2 and self.legs is not None:
            self._plants_ready(st, t)
        if not done & 1:
            jq_out[:] = joint_quality(rt.plan, self.rq[None], self.pq[None])   # something missing: held, flagged below
            c = rt.plan.checks
            if c.joint.size:
                k.flag_unfollowed(pos[0], st.pts, c.joint, c.child, c.a, c.b, c.A, c.cos_limit, jq_out[0])
        return out

    def run(self, pts, pok, rot, rok, t):
        """One frame, as LiveKernel.run: points [P, 3], rotations [R, 4] or None, masks or None."""
        k, rt = self.k, self.rt
        st = rt.state
        # writable C-contiguous inputs only: a strided or read-only view (a decoded message) would
        # compile (and cache) another variant of the kernel, seconds in a running node
        if not (pts.flags.c_contiguous and pts.flags.writeable):
            pts = np.array(pts, order="C")
        if pok is None:
            pok = self.ones_p
        elif not (pok.flags.c_contiguous and pok.flags.writeable):
            pok = np.array(pok, order="C")
        if rot is None:
            if rt.plan.point_plan is None:
                raise ValueError("this source has rotations: pass them")
            fin = np.isfinite(pts).all(-1) & pok
            rot = rotations_from_points_frame(rt.plan.point_plan, np.where(fin[:, None], pts, np.nan))
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
        good = k.retarget_frame(pts, pok, rot, rok, tf, (st.pts, st.rot, st.pts_seen, st.rot_seen, self.pq, self.rq),
                                (self.ps, self.ht, self.hxy, self.hn), (self.ci, self.cf, self.wk),
                                (root[0], pos[0], local[0], contact[0]))
        jq = self.jq_good.copy() if good else joint_quality(rt.plan, self.rq[None], self.pq[None])
        return self.Result(local, root, pos, jq, contact)
