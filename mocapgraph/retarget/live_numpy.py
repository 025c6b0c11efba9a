"""The numpy reference of the compiled one-frame path: :class:`NumpyFrame`, what the tests hold the kernels to.


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
:mod:`quat_forms`. The retargeter runs :class:`live.CompiledFrame` (the same frame through
:mod:`kernels`); this class is the readable numpy statement of that frame, built the same way
(``Retargeter(..., frame_path=NumpyFrame)``) and compared with it in the tests to 1e-12. Characters
with roll joints take the batched path on one frame instead (neither one-frame path rolls).
"""
from __future__ import annotations

import math

import numpy as np

from ..kinematics.quaternion import quat_multiply, quat_multiply_rows
from .batched import joint_quality
from .foot_planting import MOVE_M, plant_one
from .live_fold import FoldedPlan
from .quat_forms import (ID, N2_HI, N2_LO, ONES3, ONES4, PHASE, between_rows, leg_ik, left_map,
                         power_left, rotate_const, v_rotate)
from .source import rotations_from_points_frame

QUALITY_GOOD = 2


class NumpyFrame(FoldedPlan):
    """One frame in numpy from a plan folded at setup (:class:`FoldedPlan`): ``run`` gives the
    batched path's result for F = 1, as :class:`live.CompiledFrame` does."""

    def __init__(self, plan) -> None:
        super().__init__(plan)
        self._seen = None                  # the state whose seen flags are all set

    def release_state(self) -> None:
        """Before a batched call on the same state: nothing is kept apart from it here."""

    def _quat_in(self, q: np.ndarray) -> np.ndarray:
        """Δ [n, 4] of the rotate joints from the held unit source rotations [R, 4]."""
        if self.dep_idx.shape[0] == 0:
            return (q.reshape(-1) @ self.K_big).reshape(-1, 4)
        q_ext = np.concatenate([q, ID[None]])
        qk = q[self.rot_src]
        for level in self.dep_idx:          # the few dependency levels, vectorised over joints
            qk = quat_multiply_rows(qk, q_ext[level])
        return np.einsum("nml,nl->nm", self.K, qk)

    def run(self, state, pts, pok, rot, rok, t):
        """One frame on the retargeter's ``state`` (held values and plants, updated): points [P, 3],
        rotations [R, 4] (None: from the points), masks; returns the batched path's RetargetResult
        with F = 1."""
        plan = self.plan
        pts, rot, nr, all_good, rq, pq = self._held(state, pts, pok, rot, rok)
        J = self.J
        pflat = pts.reshape(-1)
        D = self._deltas(rot / nr[:, None], pts, pflat)
        # world orientations (inherited, then the rest orientation) and the parents'
        WW = (D.reshape(-1) @ self.G).reshape(J, 8)
        Wp, W = WW[:, :4], WW[:, 4:]
        # 5./6. root, positions and local rotations (w >= 0, as matrix_to_quat gives them)
        root = pflat @ self.root_big + self.root_c
        if self.root_s is not None:      # in plain floats: one numpy call, not three
            root += v_rotate(W[self.root_j].tolist(), self.root_s)
        bl = ((Wp[:, :, None] * WW[:, None, :]).reshape(J, 1, 32) @ self.both_forms)[:, 0]
        pos = root + self.anc @ bl[:, :3]
        local = bl[:, 3:]
        contact = np.zeros((1, 2), bool)
        if self.legs is not None:
            t_s = 0.0 if t is None else (t if isinstance(t, float) else float(np.asarray(t).reshape(-1)[0]))
            W2, Wp, pos, contact = self._plant(state, W, Wp, pos, root, t_s, pts)
            if W2 is not W:   # the legs moved: their local rotations anew
                local = ((Wp[:, :, None] * W2[:, None, :]).reshape(J, 1, 16) @ self.local_forms)[:, 0]
        local = local * np.copysign(1.0, local[:, :1])
        jq = self.jq_good.copy() if all_good else joint_quality(plan, rq[None], pq[None])
        return self.Result(local[None], root[None], pos[None], jq, contact)

    def _held(self, st, pts, pok, rot, rok):
        """This frame's source values with the missing ones held from the state (which is updated):
        (points [P, 3], rotations [R, 4], their norms [R], whether all were good, and, when not, the
        rotations' and points' quality [R], [P]; None when all were good)."""
        rq = pq = None
        # validity: one reduction each in the usual all-good case (NaN and inf make the sum non-finite)
        all_good = math.isfinite(pts.sum()) and (pok is None or bool(pok.all()))
        if not all_good:
            fin = np.isfinite(pts).all(-1)
            pok = fin if pok is None else (pok & fin)
        if rot is None:
            if self.plan.point_plan is None:
                raise ValueError("this source has rotations: pass them")
            rot = rotations_from_points_frame(self.plan.point_plan, pts if all_good else np.where(pok[:, None], pts, np.nan))
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
            rel = quat_multiply([qs[0], -qs[1], -qs[2], -qs[3]], qe).tolist()
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

    def _plant(self, state, W, Wp, pos, root, t: float, pts: np.ndarray):
        """batched.plant_legs for one frame: contact and targets (foot_planting.plant_one, moving with
        the held source points ``pts`` [P, 3] of the ankles), two-bone IK per leg in plain floats, the
        thigh and shin turns applied to the joints they carry."""
        plan, L, opt = self.plan, self.legs, self.plan.options
        hka = pos[L["idx"]].tolist()                      # hips, knees, ankles: l, r
        ankle = hka[4:6]
        toe_lift = None
        if L["toe"] is not None:
            tz = pos[L["toe"], 2].tolist()
            toe_lift = [opt.floor_z + L["toe_h"][i] - tz[i] for i in (0, 1)]
        k = max(plan.ratio, 1e-3)
        nan = float("nan")
        source_xy = [[plan.ratio * float(pts[s, 0]), plan.ratio * float(pts[s, 1])] if s >= 0 else [nan, nan]
                     for s in L["src_ankle"]]
        target, contact = plant_one(ankle, L["rest_h"], t, state.plant, floor_z=opt.floor_z,
                                    height_m=opt.contact_height_m * k, speed_mps=opt.contact_speed_mps * k,
                                    release_s=opt.release_s, toe_lift=toe_lift, source_xy=source_xy)
        contact = np.array([contact])
        gap = [max(abs(target[i][c] - ankle[i][c]) for c in range(3)) for i in (0, 1)]
        need = [g >= MOVE_M for g in gap]                # NaN gaps (no data) need nothing
        if not (need[0] or need[1]):
            return W, Wp, pos, contact
        hq = W[plan.legs["hip"]].tolist()
        turns = [[1.0, 0.0, 0.0, 0.0]] * 4               # thigh l, thigh r, shin l, shin r
        for i in (0, 1):   # the two legs
            if not need[i]:
                continue
            w, x, y, z = hq[i]
            pole = [1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)]   # the thigh's forward axis
            q1, q2 = leg_ik(hka[i], hka[2 + i], ankle[i], target[i], L["l1"][i], L["l2"][i], pole)
            turns[i] = q1
            turns[2 + i] = quat_multiply(q2, q1).tolist()
        aff = L["aff"]
        W = W.copy()
        W[aff] = quat_multiply_rows(np.array(turns)[L["which"]], W[aff])
        Wp = np.concatenate([W, ID[None]])[self.par_ext]
        pos = root + self.anc @ rotate_const(Wp, self.bone_forms)
        return W, Wp, pos, contact
