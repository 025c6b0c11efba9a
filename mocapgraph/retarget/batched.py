"""The batched retarget math: frames [F, ...] of held source values through a plan, as numpy arrays.

This is the reference every other path is checked against (the one-frame numpy path and the
compiled kernels give its output to 1e-12). Per frame, in the world frame (Z up, metres, rotation
matrices): Eq 4.1 on the rotate-mapped joints (with bone following), spread chains, inheritance and
aims, roll joints, the root and forward kinematics, foot planting, then local rotations (Kiip Eq 8)
and joint quality. Nothing here keeps state: the caller passes the plant state and gets it updated.
"""
from __future__ import annotations

import numpy as np

from ..kinematics.quaternion import (matrix_between, matrix_to_quat, norm, quat_conjugate, quat_multiply, quat_power,
                                     quat_rotate, quat_to_matrix, swing_twist, twist_angle)
from .bone_follow import unfollowed
from .character import Character
from .foot_planting import MOVE_M, PlantState, plant_targets, two_bone_ik
from .options import RetargetOptions, RetargetResult
from .plan import RetargetPlan

QUALITY_MISSING, QUALITY_ESTIMATED, QUALITY_GOOD = 0, 1, 2
_EYE3 = np.eye(3)


def hold_last_good(x: np.ndarray, ok: np.ndarray, last: np.ndarray, seen: np.ndarray):
    """Hold the last good value per column: (filled [F, N, ...], quality [F, N], new last, new seen)."""
    F = x.shape[0]
    if F == 1:   # the live case, without the index machinery
        extra = (slice(None),) + (None,) * (x.ndim - 2)
        filled = np.where(ok[(0,) + extra], x[0], last)[None]
        q = np.where(ok, QUALITY_GOOD, np.where(seen[None], QUALITY_ESTIMATED, QUALITY_MISSING)).astype(np.int8)
        return filled, q, filled[0].copy(), seen | ok[0]
    idx = np.where(ok, np.arange(F)[:, None], -1)
    idx = np.maximum.accumulate(idx, axis=0)
    cols = np.arange(x.shape[1])[None, :]
    got = x[np.maximum(idx, 0), cols]
    filled = np.where((idx >= 0)[..., None], got, last[None])
    q = np.where(ok, QUALITY_GOOD, np.where((idx >= 0) | seen[None], QUALITY_ESTIMATED, QUALITY_MISSING))
    return filled, q.astype(np.int8), filled[-1].copy(), seen | (idx[-1] >= 0)


def retarget_frames(plan: RetargetPlan, ch: Character, opt: RetargetOptions, plant: PlantState,
                    rot: np.ndarray, rq: np.ndarray, pts: np.ndarray, pq: np.ndarray,
                    times_s: np.ndarray | float | None) -> RetargetResult:
    """Held source rotations [F, R, 4] and points [F, P, 3] with their quality [F, R], [F, P] onto
    the character; ``times_s`` [F] s (None: frame numbers) for the planting speeds."""
    F = pts.shape[0]
    world = world_rotations(plan, ch, rot, pts)
    root = root_position(plan, opt, pts[:, plan.root_src])
    if plan.root_s is not None:   # the formula gave the mid-hip: the root sits off it, turning with the root
        root = root + world[:, plan.root] @ plan.root_s
    pos = positions(plan, ch, world, root)
    contact = np.zeros((F, 2), bool)
    if plan.legs is not None:
        t = np.arange(F, dtype=float) if times_s is None else np.asarray(times_s, float).reshape(-1)
        world, pos, contact = plant_legs(plan, ch, opt, plant, world, pos, root, t, pts)
    # local rotations: rest⁻¹ · W[parent]⁻¹ · W
    parent_w = world[:, plan.parents]
    parent_w[:, plan.root] = _EYE3
    local = plan.rest_local_inv @ np.swapaxes(parent_w, -1, -2) @ world
    quality = joint_quality(plan, rq, pq)
    if not plan.checks.empty:
        quality = np.where(unfollowed(plan.checks, pos, pts), np.minimum(quality, QUALITY_ESTIMATED), quality)
    return RetargetResult(matrix_to_quat(local), root, pos, quality.astype(np.int8), contact)


def world_rotations(plan: RetargetPlan, ch: Character, rot: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """World orientations [F, J, 3, 3]: Eq 4.1 (Δ = A · Q_k · D · R⁻¹ · A⁻¹) with bone following,
    spread chains, aims, inheritance onto the rest orientations, roll joints."""
    F, J = pts.shape[0], ch.n_joints
    qk = rot[:, plan.rot_src]
    for i, deps in plan.dep:
        for d in deps:
            qk[:, i] = quat_multiply(qk[:, i], rot[:, d])
    delta = np.broadcast_to(plan.eye_j, (F, J, 3, 3)).copy()
    d_rot = plan.A @ quat_to_matrix(qk) @ plan.post
    if len(plan.follow_m):
        sub = d_rot[:, plan.follow_m]
        have = (sub @ plan.follow_bone[..., None])[..., 0]
        A = plan.A[plan.follow_m]
        want = (A @ (pts[:, plan.follow_b] - pts[:, plan.follow_a])[..., None])[..., 0]
        ok = norm(want) > 1e-9
        turn = matrix_between(have, np.where(ok[..., None], want, have))
        d_rot[:, plan.follow_m] = turn @ sub
    delta[:, plan.rot_joint] = d_rot
    for c in plan.chains:
        _spread(c, delta, pts)
    if plan.aims:
        delta_all = delta[:, plan.src_pre]
        for j, b, frm, to, A in plan.aims:
            dp = delta_all[:, ch.parents[j]]
            carried = (dp @ b[:, None])[..., 0]
            want = (A @ (pts[:, to] - pts[:, frm])[..., None])[..., 0]
            delta[:, j] = matrix_between(carried, want) @ dp
    delta_all = delta[:, np.maximum(plan.src_post, 0)]
    if plan.undriven.size:
        delta_all[:, plan.undriven] = _EYE3
    world = delta_all @ plan.rest_world                     # [F, J, 3, 3]
    for r, o, f, upper in plan.rolls:
        world = apply_roll(ch, world, r, o, f, upper)
    return world


def _spread(c: dict, delta: np.ndarray, pts: np.ndarray) -> None:
    """One spread chain in place: its joints share the turn from start to end (Kiip 3.5.3), then
    the chain is turned so that its end point lies on the scaled source end point."""
    qse = matrix_to_quat(delta[:, c["ends"]])            # start and end in one call
    qs, qe = qse[:, 0], qse[:, 1]
    rel = quat_multiply(quat_conjugate(qs), qe)
    qi = quat_multiply(qs[:, None], quat_power(rel[:, None], c["frac"][None, :]))
    delta[:, c["joints"]] = quat_to_matrix(qi)
    if c["end_src"] >= 0 and c["pivot_src"] >= 0 and np.isfinite(c["ratio"]):
        target = c["ratio"] * (c["A"] @ (pts[:, c["end_src"]] - pts[:, c["pivot_src"]])[..., None])[..., 0]
        path = c["path"]
        for _ in range(1 if c["endpt"] == c["end"] else 4):
            vec = np.einsum("fkij,kj->fi", delta[:, path], c["offsets"])
            corr = matrix_between(vec, target)
            delta[:, c["joints"]] = corr[:, None] @ delta[:, c["joints"]]


def joint_quality(plan: RetargetPlan, rq: np.ndarray, pq: np.ndarray) -> np.ndarray:
    """Joint quality [F, J] from the source rotations' and points' [F, R], [F, P]: a joint is as good
    as the worst of what drives it and of every joint above it."""
    F, J = rq.shape[0], len(plan.parents)
    jq = np.full((F, J), QUALITY_GOOD, np.int8)
    jq[:, plan.rot_joint] = rq[:, plan.rot_src]
    if len(plan.follow_m):   # a bone aimed at held points is estimated too
        fj = plan.rot_joint[plan.follow_m]
        jq[:, fj] = np.minimum(jq[:, fj], np.minimum(pq[:, plan.follow_a], pq[:, plan.follow_b]))
    for c in plan.chains:
        jq[:, c["joints"]] = np.minimum(jq[:, [c["start"]]], jq[:, [c["end"]]])
        if c["end_src"] >= 0 and c["pivot_src"] >= 0:
            jq[:, c["joints"]] = np.minimum(jq[:, c["joints"]],
                                            np.minimum(pq[:, [c["end_src"]]], pq[:, [c["pivot_src"]]]))
    for j, _b, frm, to, _A in plan.aims:
        jq[:, j] = np.minimum(pq[:, to], pq[:, frm])
    jq = jq[:, np.maximum(plan.src_post, 0)]
    jq[:, plan.root] = np.minimum(jq[:, plan.root], pq[:, plan.root_src])
    return np.where(plan.anc_full[None], jq[:, None, :], 9).min(-1).astype(np.int8)


def root_position(plan: RetargetPlan, opt: RetargetOptions, src_root: np.ndarray) -> np.ndarray:
    """Root [F, 3] m: horizontal source root [F, 3] times the ratio (A applied), height matched at the floor."""
    p = (plan.root_A @ src_root[..., None])[..., 0] * plan.ratio
    p[:, 2] = plan.h_c + plan.ratio * (src_root[:, 2] - plan.h_s) + opt.floor_z
    return p + plan.offset


def positions(plan: RetargetPlan, ch: Character, world: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Joint positions [F, J, 3] m: the root plus every ancestor's rest bone turned by its parent's world rotation."""
    bones = (world[:, plan.parents] @ ch.rest_offsets[:, :, None])[..., 0]
    return root[:, None, :] + np.einsum("jk,fkd->fjd", plan.anc, bones)


def apply_roll(ch: Character, world: np.ndarray, r: int, o: int, f: float, upper: bool) -> np.ndarray:
    """Roll joint ``r`` takes the fraction ``f`` of joint ``o``'s twist about their bone (Kiip 3.5.5);
    ``upper``: r hangs from o. Returns ``world`` [F, J, 3, 3], changed in place."""
    rest_q = ch.rest_rotations
    wq = matrix_to_quat(world)
    if upper:   # r hangs from o: o keeps (1 - f) of its twist about the o->r bone, r takes f
        par = ch.parents[o]
        pw = wq[:, par] if par >= 0 else np.array([1.0, 0, 0, 0])
        local_o = quat_multiply(quat_conjugate(quat_multiply(pw, rest_q[o])), wq[:, o])
        axis = ch.rest_offsets[r] / np.linalg.norm(ch.rest_offsets[r])
        _, tw = swing_twist(local_o, axis)
        world[:, o] = quat_to_matrix(quat_multiply(wq[:, o], quat_power(quat_conjugate(tw), f)))
    else:       # o hangs from r: r takes f of o's twist about the r->o bone
        local_o = quat_multiply(quat_conjugate(quat_multiply(wq[:, r], rest_q[o])), wq[:, o])
        axis_o = quat_rotate(quat_conjugate(rest_q[o]), ch.rest_offsets[o] / np.linalg.norm(ch.rest_offsets[o]))
        _, tw = swing_twist(local_o, axis_o)
        ang = twist_angle(tw, axis_o) * f
        ax = ch.rest_offsets[o] / np.linalg.norm(ch.rest_offsets[o])      # in r's frame
        turn = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * ax], axis=1)
        world[:, r] = quat_to_matrix(quat_multiply(wq[:, r], turn))
    return world


def plant_legs(plan: RetargetPlan, ch: Character, opt: RetargetOptions, plant: PlantState, world: np.ndarray,
               pos: np.ndarray, root: np.ndarray, t: np.ndarray, pts: np.ndarray):
    """Foot planting (Kiip 3.5.6): contact per leg, planted ankles held by two-bone leg IK (moving
    only as the source points ``pts`` [F, P, 3] of the ankles do, scaled by the root ratio), soles
    above the floor; ``plant`` is updated. Returns (world, positions, contact [F, 2])."""
    L = plan.legs
    ankle = pos[:, L["ankle"]]
    has = L["src_ankle"] >= 0
    source_xy = np.where(has[None, :, None], plan.ratio * pts[:, np.maximum(L["src_ankle"], 0), :2], np.nan)
    toe_lift = None
    if (L["toe"] >= 0).all():
        toe_lift = (opt.floor_z + L["toe_h"]) - pos[:, L["toe"], 2]
    # thresholds are for a performer-sized character: a bigger one moves (and jitters) faster
    k = max(plan.ratio, 1e-3)
    target, contact = plant_targets(ankle, L["rest_h"], t, plant, floor_z=opt.floor_z,
                                    height_m=opt.contact_height_m * k, speed_mps=opt.contact_speed_mps * k,
                                    release_s=opt.release_s, toe_lift=toe_lift, source_xy=source_xy)
    if np.abs(target - ankle).max(initial=0.0) < MOVE_M or not np.isfinite(target).any():
        return world, pos, contact          # nothing to correct (free feet above the floor)
    hip, knee = pos[:, L["hip"]], pos[:, L["knee"]]
    pole = (world[:, L["hip"]] @ np.array([1.0, 0.0, 0.0]))  # the thigh's forward axis
    s1, s2, _ = two_bone_ik(hip, knee, ankle, target, L["l1"][None], L["l2"][None], pole)
    # a foot already where it should be keeps its leg (IK would bend a straight one by its reach margin),
    # so a frame's result does not depend on the other frames of its batch
    need = (np.abs(target - ankle).max(-1) >= MOVE_M)[..., None, None]
    s1, s2 = np.where(need, s1, _EYE3), np.where(need, s2, _EYE3)
    for i in range(2):
        above_knee = L["sub"][i].copy()
        thigh = above_knee & ~L["below_knee"][i]
        shin = above_knee & L["below_knee"][i]
        world[:, thigh] = s1[:, i, None] @ world[:, thigh]
        world[:, shin] = (s2[:, i] @ s1[:, i])[:, None] @ world[:, shin]
    return world, positions(plan, ch, world, root), contact
