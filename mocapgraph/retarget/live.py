"""The retargeter's compiled one-frame path: :meth:`Retargeter.process` for a single frame in one kernel call.

Same math and same output as the batched path (to rounding, checked in the tests), with the
world-frame rotations as wxyz quaternions and everything that does not change per frame folded
when the retargeter is built (:mod:`live_fold`, whose algebra :mod:`live_numpy` explains):
:class:`CompiledFrame` lays the folded constants and the frame's scratch into one
:class:`frame_plan.FramePlan` and runs each frame through :mod:`kernels` in one call (for a solved
actor, the point layout, masks and bone-follow flags included). It holds the plants of the state
it last ran as arrays and hands them back (:meth:`CompiledFrame.release_state`) before a batched
call reads them. :class:`live_numpy.NumpyFrame` is the same frame in numpy, the reference the tests
hold it to. Joint quality is the batched path's own code, skipped when every input is good.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..kinematics.quaternion import matrix_to_quat
from .batched import joint_quality
from .live_fold import FoldedPlan
from .source import pelvis_hips, rotations_from_points_frame

if TYPE_CHECKING:   # annotations only
    from .plan import RetargetPlan


def _pack_plant(plant, ps: np.ndarray, cap: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A PlantState into the compiled path's arrays (kernels' layout): fills ``ps`` [17],
    returns (times [cap'], xy [cap', 4], count [1]) with cap' >= cap and room for one more sample."""
    ps[0:2] = plant.planted
    ps[2:6] = np.asarray(plant.anchor, float).reshape(4)
    ps[6:10] = np.asarray(plant.offset, float).reshape(4)
    ps[10] = plant.last_t
    ps[11:13] = plant.low
    ps[13:17] = np.asarray(plant.src_last, float).reshape(4)
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
    plant.src_last = ps[13:17].reshape(2, 2).copy()
    plant.history_t = ht[:n].tolist()
    plant.history_xy = list(hxy[:n].reshape(n, 2, 2).copy())


class CompiledFrame:
    """The one-frame path as numba kernels (:mod:`kernels`): a folded plan's constants as one
    :class:`frame_plan.FramePlan`, scratch preallocated; ``run`` gives the batched path's result for
    F = 1 (to rounding; :class:`live_numpy.NumpyFrame` is its numpy reference, tested)."""

    def __init__(self, plan: "RetargetPlan") -> None:
        from . import kernels as rk
        self.k = rk
        lk = FoldedPlan(plan)
        ch, J = plan.character, lk.J
        self.plan, self.J = plan, J
        i64 = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.int64).reshape(-1))   # noqa: E731
        f64 = lambda a, *shape: np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(shape))  # noqa: E731
        n = len(lk.rot_src)
        self.rot_src, self.rot_joint = i64(lk.rot_src), i64(lk.rot_joint)
        self.dep_idx = np.ascontiguousarray(lk.dep_idx, dtype=np.int64).reshape(-1, n)
        self.K = f64(lk.K, n, 4, 4)
        nf = len(plan.follow_m)
        self.f_m, self.f_a, self.f_b = i64(plan.follow_m), i64(plan.follow_a), i64(plan.follow_b)
        self.f_bone = f64(plan.follow_bone, nf, 3)
        self.f_A = f64(plan.A[plan.follow_m] if nf else np.zeros((0, 3, 3)), nf, 3, 3)
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
        offs = [c["offsets"] if lc["correct"] else np.zeros((0, 3)) for c, lc in zip(plan.chains, cs)]
        self.c_off = f64(np.concatenate(offs) if offs else [], -1, 3)
        a = lk.aims
        na = 0 if a is None else len(a["joint"])
        self.a_joint, self.a_pre = i64(a["joint"] if na else []), i64(a["pre"] if na else [])
        self.a_bone = f64([x[1] for x in plan.aims] if na else [], na, 3)
        self.a_frm, self.a_to = i64(a["frm"] if na else []), i64(a["to"] if na else [])
        self.a_A = f64(a["A"] if na else [], na, 3, 3)
        self.src_ext = i64(np.where(plan.src_post < 0, J, plan.src_post))
        self.rw_q = f64(matrix_to_quat(plan.rest_world), J, 4)
        self.parents = i64(ch.parents)
        order, seen = [], set()
        while len(order) < J:   # parents first (the character has no cycle: checked when loaded)
            for j in range(J):
                if j not in seen and (ch.parents[j] < 0 or ch.parents[j] in seen):
                    order.append(j)
                    seen.add(j)
        self.order = i64(order)
        self.offsets = f64(ch.rest_offsets, J, 3)
        rl = matrix_to_quat(np.swapaxes(plan.rest_local_inv, -1, -2))   # rest_local, conjugated
        rl[:, 1:] *= -1.0
        self.rl_inv = f64(rl, J, 4)
        self.root_src = int(plan.root_src)
        self.root_M, self.root_c = f64(lk.root_M, 3, 3), f64(lk.root_c, 3)
        P, R = len(plan.source.point_names), len(plan.source.rotation_names)
        self.ones_p, self.ones_r = np.ones(P, np.bool_), np.ones(R, np.bool_)
        self.check_norm = plan.point_plan is None
        # source qualities of the last frame (read when a frame was not all good); scratch: self.frame_plan
        self.pq, self.rq = np.empty(P, np.int8), np.empty(R, np.int8)
        self.jq_good = lk.jq_good
        # an optical actor's joints (the source's points but the pelvis, last) and the hips whose
        # mean the pelvis is: the actor frame lays them out in the kernel (run_actor)
        self.hips = None
        if plan.source.kind == "optical":
            self.hips = i64(pelvis_hips(plan.source.point_names[:-1]))
        self.actor_shapes = ((P - 1, 3), (P - 1,), (R, 4), (R,))
        chk = plan.checks
        self.Result = lk.Result
        self.legs = None
        if lk.legs is not None:
            L, opt = plan.legs, plan.options
            k = max(plan.ratio, 1e-3)
            self.legs = (i64(L["hip"]), i64(L["knee"]), i64(L["ankle"]), i64(np.maximum(L["toe"], 0)),
                         bool((L["toe"] >= 0).all()), f64(L["l1"], 2), f64(L["l2"], 2), f64(L["rest_h"], 2),
                         f64(np.nan_to_num(L["toe_h"]), 2), i64(lk.legs["aff"]), i64(lk.legs["which"]))
            self.plant_params = (float(opt.floor_z), float(opt.contact_height_m * k), float(opt.contact_speed_mps * k),
                                 float(opt.release_s), 0.05)   # plant_one's window_s
            self.ps = np.zeros(17)
            self.ht, self.hxy, self.hn = np.zeros(64), np.zeros((64, 4)), np.zeros(1, np.int64)
        self._plant_for = None      # the retargeter state whose plants the arrays above hold
        self._out_checked = None    # the last ``out`` of run_actor found to fit (see _check_out)
        if self.legs is None:       # the frame kernel's plant arguments, unused
            self.ps, self.ht, self.hxy, self.hn = np.zeros(17), np.zeros(2), np.zeros((2, 4)), np.zeros(1, np.int64)
        self.frame_plan = self._frame_plan(lk, n, na, P, R)

    def _frame_plan(self, lk: FoldedPlan, n: int, na: int, P: int, R: int):
        """The kernels' :class:`frame_plan.FramePlan`: this object's constant arrays by field name, the
        legs' and the bone checks', and the frame's scratch (zeros of each field's shape)."""
        from .frame_plan import build
        plan, J = self.plan, self.J
        z_i, z_f = np.zeros(0, np.int64), np.zeros(0)
        hip, knee, ankle, toe, has_toe, l1, l2, rest_h, toe_h, aff, which = self.legs or (
            z_i, z_i, z_i, z_i, False, z_f, z_f, z_f, z_f, z_i, z_i)
        floor_z, height_m, speed_mps, release_s, window_s = self.plant_params if self.legs else (0.0,) * 5
        chk = plan.checks
        names = ("rot_src", "dep_idx", "K", "rot_joint", "f_m", "f_a", "f_b", "f_bone", "f_A", "c_start", "c_end",
                 "c_jptr", "c_joints", "c_frac", "c_iters", "c_correct", "c_end_src", "c_pivot_src", "c_A", "c_pptr",
                 "c_path", "c_off", "a_joint", "a_pre", "a_bone", "a_frm", "a_to", "a_A", "src_ext", "rw_q",
                 "root_src", "root_M", "root_c", "parents", "order", "offsets", "rl_inv", "check_norm")
        values = {name: getattr(self, name) for name in names}
        values.update(
            root_joint=lk.root_j, root_s=np.zeros(3) if plan.root_s is None else plan.root_s,
            has_legs=self.legs is not None, has_toe=has_toe, hip=hip, knee=knee, ankle=ankle, toe=toe, l1=l1, l2=l2,
            rest_h=rest_h, toe_h=toe_h, aff=aff, which=which, floor_z=floor_z, height_m=height_m,
            speed_mps=speed_mps, release_s=release_s, window_s=window_s,
            hips=self.hips if self.hips is not None else z_i, b_joint=chk.joint, b_child=chk.child, b_a=chk.a,
            b_b=chk.b, b_A=np.asarray(chk.A, float).reshape(-1, 3, 3), b_cos=chk.cos_limit,
            # scratch
            qn=np.zeros((R, 4)), qk=np.zeros((max(n, 1), 4)), dq=np.zeros((max(n, 1), 4)),
            ap=np.zeros((max(na, 1), 4)), D=np.zeros((J + 1, 4)), W=np.zeros((J, 4)), tmp=np.zeros((2, 4)),
            ank=np.zeros((2, 3)), toe_z=np.zeros(2), target=np.zeros((2, 3)), speed=np.zeros(2),
            turns=np.zeros((4, 4)), pin=np.zeros((P, 3)), pin_ok=np.zeros(P, np.bool_), rot_ok=np.zeros(R, np.bool_),
            src_ankle=plan.legs["src_ankle"] if self.legs else z_i, src_scale=float(plan.ratio), src_xy=np.zeros((2, 2)))
        return build(values)

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

    def run_actor(self, st, jp, jq, rot, lq, t, out=None):
        """One solved-actor frame on the retargeter's state ``st`` (optical source) at time ``t`` (s, a float): joints [J, 3], quality [J],
        limb rotations [R, 4], quality [R] (int8), C-contiguous as a message holds them, all read-only (decoded) or all
        writable (the two compiled variants); :meth:`run` of OpticalFrames' points and the limbs of
        quality >= 1, with the bone-follow flags, in one kernel call. ``out`` (from :meth:`buffers`):
        written and returned instead of a new result (a caller that hands the arrays on before the
        next frame, as the node does, allocates nothing per frame)."""
        if (jp.shape, jq.shape, rot.shape, lq.shape) != self.actor_shapes:   # the kernel does not check bounds
            raise ValueError(f"an actor frame of this source wants joints {self.actor_shapes[0]}, quality "
                             f"{self.actor_shapes[1]}, limbs {self.actor_shapes[2]}, {self.actor_shapes[3]}")
        k, plan = self.k, self.plan
        if self._plant_for is not st:   # (after that, the kernel's return value says when the window needs room)
            self._plants_ready(st, t)
        if out is None:
            out = self.buffers()
        elif out is not self._out_checked:   # the kernel writes without bounds checks: once per buffer set
            self._check_out(out)
        local, root, pos, jq_out, contact = (out.local_rotations, out.root_positions, out.joint_positions,
                                             out.joint_quality, out.contact)
        done = k.retarget_actor_frame(jp, jq, rot, lq, t, (st.pts, st.rot, st.pts_seen, st.rot_seen, self.pq, self.rq),
                                      (self.ps, self.ht, self.hxy, self.hn), self.frame_plan,
                                      (root, pos, local, contact, jq_out))
        if done & 2 and self.legs is not None:
            self._plants_ready(st, t)
        if not done & 1:
            jq_out[:] = joint_quality(plan, self.rq[None], self.pq[None])   # something missing: held, flagged below
            c = plan.checks
            if c.joint.size:
                k.flag_unfollowed(pos[0], st.pts, c.joint, c.child, c.a, c.b, c.A, c.cos_limit, jq_out[0])
        return out

    def run(self, st, pts, pok, rot, rok, t):
        """One frame on the retargeter's state ``st`` (held values and plants, updated): points
        [P, 3], rotations [R, 4] or None, masks or None."""
        k, plan = self.k, self.plan
        # writable C-contiguous inputs only: a strided or read-only view (a decoded message) would
        # compile (and cache) another variant of the kernel, seconds in a running node
        if not (pts.flags.c_contiguous and pts.flags.writeable):
            pts = np.array(pts, order="C")
        if pok is None:
            pok = self.ones_p
        elif not (pok.flags.c_contiguous and pok.flags.writeable):
            pok = np.array(pok, order="C")
        if rot is None:
            if plan.point_plan is None:
                raise ValueError("this source has rotations: pass them")
            fin = np.isfinite(pts).all(-1) & pok
            rot = rotations_from_points_frame(plan.point_plan, np.where(fin[:, None], pts, np.nan))
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
                                (self.ps, self.ht, self.hxy, self.hn), self.frame_plan,
                                (root[0], pos[0], local[0], contact[0]))
        jq = self.jq_good.copy() if good else joint_quality(plan, self.rq[None], self.pq[None])
        return self.Result(local, root, pos, jq, contact)
