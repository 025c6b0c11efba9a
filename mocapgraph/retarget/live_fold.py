"""The retarget plan folded for one frame: every constant of the one-frame path as arrays and forms.

What does not change per frame is folded when the retargeter is built (see :mod:`live` for why):
Eq 4.1's constant factors as 4x4 maps, the source gathers as linear maps of the flat source arrays,
rest bones as quadratic forms of the world quaternions, inheritance and rest orientations as one
linear map, local rotations as a bilinear form. Indices as in :mod:`plan`; metres, wxyz.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..kinematics.quaternion import matrix_to_quat
from .options import RetargetResult
from .quat_forms import CONJ16, HAM, ID, ROT, left_map, right_map

if TYPE_CHECKING:   # annotations only
    from .plan import RetargetPlan

QUALITY_GOOD = 2


class FoldedPlan:
    """The folded constants of one retarget plan (the attributes the one-frame paths read)."""

    def __init__(self, plan: "RetargetPlan") -> None:
        self.plan, self.J = plan, plan.character.n_joints
        self._fold_eq41(plan)
        self._fold_follow(plan)
        self._fold_chains(plan)
        self._fold_aims(plan)
        self._fold_world(plan)
        self.jq_good = np.full((1, self.J), QUALITY_GOOD, np.int8)
        self.Result = RetargetResult
        self._fold_root(plan)
        self._fold_legs(plan)
        self._fold_local(plan)

    def _fold_eq41(self, plan: "RetargetPlan") -> None:
        """Eq 4.1 as one 4x4 map K per rotate joint on Q_k; with no source dependencies, the gather too."""
        mp = plan.mapping
        rot = [e for e in mp.joints if e.mode == "rotate" and e.rotation is not None]
        n = len(rot)
        a_q = [np.asarray(e.A, float) / np.linalg.norm(e.A) for e in rot]
        post_q = matrix_to_quat(plan.post) if n else np.zeros((0, 4))
        K = np.array([left_map(a) @ right_map(p) for a, p in zip(a_q, post_q)]).reshape(n, 4, 4)
        self.K = K
        R = len(plan.source.rotation_names)
        self.rot_src = plan.rot_src
        self.rot_joint = plan.rot_joint
        # source dependencies, level by level: qk[i] *= rot_ext[dep_idx[level, i]] (R: identity slot)
        deps = {i: d for i, d in plan.dep}
        depth = max((len(d) for d in deps.values()), default=0)
        self.dep_idx = np.full((depth, n), R, dtype=np.int64)
        for i, d in deps.items():
            self.dep_idx[:len(d), i] = d
        if depth == 0:   # gather and Eq 4.1 in one product
            big = np.zeros((4 * R, 4 * n))
            for i in range(n):
                big[4 * self.rot_src[i]:4 * self.rot_src[i] + 4, 4 * i:4 * i + 4] += K[i].T
            self.K_big = big

    def _fold_follow(self, plan: "RetargetPlan") -> None:
        """Bone following: the rest bones as quadratic forms, the source bones as one linear map of the points."""
        self.follow_m = plan.follow_m
        self.follow_forms = ROT @ plan.follow_bone[:, None, :, None] if len(plan.follow_m) else None
        if self.follow_forms is not None:
            self.follow_forms = self.follow_forms[..., 0]                                   # [nf, 16, 3]
            self.follow_len = np.linalg.norm(plan.follow_bone, axis=1)
            P = len(plan.source.point_names)
            nf = len(plan.follow_m)
            w = np.zeros((3 * P, 3 * nf))   # want = A (p_b - p_a), flat
            for i in range(nf):
                A = plan.A[plan.follow_m[i]]
                w[3 * plan.follow_b[i]:3 * plan.follow_b[i] + 3, 3 * i:3 * i + 3] += A.T
                w[3 * plan.follow_a[i]:3 * plan.follow_a[i] + 3, 3 * i:3 * i + 3] -= A.T
            self.follow_w = w

    def _fold_chains(self, plan: "RetargetPlan") -> None:
        """Spread chains: their shares and the end-point correction's constants."""
        self.chains = []
        for c in plan.chains:
            d = dict(start=c["start"], end=c["end"], joints=c["joints"], frac=c["frac"], path=c["path"],
                     f2=np.repeat(np.asarray(c["frac"], float)[:, None], 2, axis=1),
                     iters=1 if c["endpt"] == c["end"] else 4,
                     correct=c["end_src"] >= 0 and c["pivot_src"] >= 0 and bool(np.isfinite(c["ratio"])),
                     end_src=c["end_src"], pivot_src=c["pivot_src"], A=c["ratio"] * c["A"])
            if d["correct"]:
                d["forms"] = (ROT @ c["offsets"][:, None, :, None])[..., 0]
            self.chains.append(d)

    def _fold_aims(self, plan: "RetargetPlan") -> None:
        """Aims, vectorised over the aim joints (each hangs from a joint not aimed itself)."""
        ch, J = plan.character, self.J
        self.aims = None
        if plan.aims:
            par = np.array([ch.parents[a[0]] for a in plan.aims])
            pre = plan.src_pre[par]
            pre = np.where(pre < 0, pre + J, pre)   # the batched path's index, Python's negative wrap included
            self.aims = dict(joint=plan.aim_joint, pre=pre,
                             forms=(ROT @ np.array([a[1] for a in plan.aims])[:, None, :, None])[..., 0],
                             frm=np.array([a[2] for a in plan.aims]), to=np.array([a[3] for a in plan.aims]),
                             A=np.array([a[4] for a in plan.aims]))

    def _fold_world(self, plan: "RetargetPlan") -> None:
        """Inheritance and rest orientation: W[j] = Δ_ext[s_j] · rest_world_q[j] (identity slot J), as one product."""
        ch, J = plan.character, self.J
        src = np.where(plan.src_post < 0, J, plan.src_post)
        rw_q = matrix_to_quat(plan.rest_world)
        par = np.where(ch.parents < 0, J, ch.parents)
        self.par_ext = par
        # one product gives every W and every W[parent] (the root's parent: the identity slot)
        # laid out per joint as [W[parent] | W] (8 columns), the pair the last step multiplies
        g = np.zeros((4 * (J + 1), 8 * J))
        for j in range(J):
            g[4 * src[j]:4 * src[j] + 4, 8 * j + 4:8 * j + 8] += right_map(rw_q[j]).T
            p = par[j]
            if p < J:
                g[4 * src[p]:4 * src[p] + 4, 8 * j:8 * j + 4] += right_map(rw_q[p]).T
            else:
                g[4 * J:4 * J + 4, 8 * j:8 * j + 4] += np.eye(4)
        self.G = g
        self.delta0 = np.tile(ID, (J + 1, 1))

    def _fold_root(self, plan: "RetargetPlan") -> None:
        """Positions: bones R(W[parent]) · offset summed over ancestors; the root from the source root (one map)."""
        ch = plan.character
        self.bone_forms = (ROT @ ch.rest_offsets[:, None, :, None])[..., 0]                # [J, 16, 3]
        self.anc = plan.anc
        M = np.zeros((3, 3))
        M[:2] = plan.ratio * plan.root_A[:2]
        M[2, 2] = plan.ratio
        self.root_M = M
        big = np.zeros((3 * len(plan.source.point_names), 3))
        big[3 * plan.root_src:3 * plan.root_src + 3] = M.T       # the source root's gather folded in
        self.root_big = big
        self.root_c = np.array([0.0, 0.0, plan.h_c - plan.ratio * plan.h_s + plan.options.floor_z]) + plan.offset
        self.root_src = plan.root_src
        # the mid-hip rule (plan._midhip_rule): root += R(W[root]) s
        self.root_j = int(plan.root)
        self.root_s = None if plan.root_s is None else [float(v) for v in plan.root_s]

    def _fold_legs(self, plan: "RetargetPlan") -> None:
        """Foot planting: the joints each leg's thigh and shin turns carry."""
        self.legs = None
        if plan.legs is not None:
            L = plan.legs
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
                             toe_h=L["toe_h"].tolist(), src_ankle=L["src_ankle"].tolist())

    def _fold_local(self, plan: "RetargetPlan") -> None:
        """Local rotations (rest_local⁻¹ · conj(W[parent]) · W) as a bilinear form per joint, beside the bone vectors."""
        J = self.J
        rl_inv = matrix_to_quat(np.swapaxes(plan.rest_local_inv, -1, -2))   # rest_local, then conjugated
        rl_inv[:, 1:] *= -1.0
        self.local_forms = np.stack([(HAM * CONJ16) @ left_map(rl_inv[j]).T for j in range(J)])  # [J, 16, 4]
        # both at once from W[parent] ⊗ [W[parent] | W] [J, 32]: the bone vector (3) and the local rotation (4)
        both = np.zeros((J, 4, 8, 7))
        both[:, :, :4, :3] = self.bone_forms.reshape(J, 4, 4, 3)
        both[:, :, 4:, 3:] = self.local_forms.reshape(J, 4, 4, 4)
        self.both_forms = both.reshape(J, 32, 7)
