"""Numpy references of the physics world's kernels, with the kernels' signatures: the tests run both.

:data:`REFERENCE` is :class:`.world.Kernels` of numpy functions doing, array at a time, what
:mod:`.controller_kernels` and :mod:`.state_kernels` do element by element (Eq 1 terms and forces,
Eq 2 torques, wrenches into ``xfrc_applied``, targets, foot pins, read-out); a world built with
``PhysicsWorld(..., kernels=REFERENCE)`` runs them. :class:`ReferenceConditioner` is the numpy
reference of :class:`.tracker.TargetConditioner` (the posture database's :func:`complete`,
world orientations by quaternion products). Same units and frames as the kernels (SI, world Z up,
wxyz); the tests hold both to ~1e-12.
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..kinematics.quaternion import (matrix_to_quat, quat_conjugate, quat_multiply, quat_multiply_conj_rows,
                                     quat_multiply_rows)
from .controller import Gains, cross, twist_torques
from .posture_db import PostureDB, normalise_one, rz_rows
from .tracker import Conditioned, TargetConditioner
from .world import Kernels

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def frame_terms(tgt, kp_pt, kd_pt, span, ts, terms) -> None:
    """:func:`.controller_kernels.frame_terms`: a positional constraint (override, then the dodge's)
    replaces the target and holds still; a point without a target gets zero gains."""
    p_t, v_t, override, dodge = tgt
    c0, slope, kp, kd = terms
    fixed = np.isfinite(override) | np.isfinite(dodge)
    target = np.where(np.isfinite(override), override, p_t)
    target = np.where(np.isfinite(dodge), dodge, target)
    vel = np.where(fixed, 0.0, v_t)   # a positional constraint holds still
    # per frame, not per substep: a point without a target gets zero gains (so no force) and
    # finite zeros for its target
    mask = np.isfinite(target).all(1)[:, None]
    k_p, k_d = kp_pt[:, None] * mask, kd_pt[:, None] * mask
    target = np.where(mask, target, 0.0)
    vel = np.where(mask, vel, 0.0)
    # Eq 1 is f = Ke (p_t - p) + Kd (v_t - v) with targets moving on between frames at their
    # velocity (the input arrives per frame): f = c0 + (i + 1) slope - Ke p - Kd v at substep i
    c0[:] = k_p * (target - vel * span) + k_d * vel
    slope[:] = k_p * vel * ts
    kp[:] = k_p[:, 0]
    kd[:] = k_d[:, 0]


def apply_wrenches(sim, pts, f, b_body, tq) -> None:
    """:func:`.controller_kernels.apply_wrenches`: torques ``tq`` on ``b_body`` plus each point
    force at its site, ``[f, (p - xipos) x f]``, summed per body."""
    site_xpos, _, _, xipos, _, _, xfrc = sim
    site, body = pts[0], pts[1]
    xfrc[:] = 0.0
    xfrc[b_body, 3:] = tq
    arm = site_xpos[site] - xipos[body]
    np.add.at(xfrc, body, np.concatenate([f, cross(arm, f)], axis=1))


def substep_control(sim, pts, bod, terms, rot, gains, step, f, tq, tops) -> None:
    """:func:`.controller_kernels.substep_control`: Eq 2 on the first substep, Eq 1 (bounded), both
    into ``xfrc_applied``."""
    site_xpos, cvel, subtree_com, _, xquat, xmat, _ = sim
    site, body, root, bound = pts
    c0, slope, kp, kd = terms
    p = site_xpos[site]
    cv = cvel[body]
    v = cv[:, 3:] + cross(cv[:, :3], p - subtree_com[root])
    fr = (c0 + slope * (step + 1)) - kp[:, None] * p - kd[:, None] * v   # Eq 1, gains premultiplied
    fr = np.where(np.isfinite(fr), fr, 0.0)   # a blown-up state: no force from it
    norm2 = (fr * fr).sum(1)
    if (norm2 > bound ** 2).any():            # clip_norm, skipped when nothing is over its bound
        fr *= np.minimum(1.0, bound / np.sqrt(np.maximum(norm2, 1e-24)))[:, None]
    f[:] = fr
    tops[0] = float((fr * fr).sum(1).max(initial=0.0))
    if step == 0:
        # Eq 2 once per frame, held over its substeps: gains per unit inertia keep Kd_rot * frame
        # span well inside the stable range
        b, b_axis, scale = bod
        q_t, w_t, has_rot = rot
        axis = (xmat[b].reshape(-1, 3, 3) @ b_axis[:, :, None])[:, :, 0]
        g = Gains(kp_rot=gains[0], kd_rot=gains[1], max_torque=gains[2])
        tq[:] = twist_torques(g, xquat[b], cvel[b, :3], axis, q_t, w_t, scale) * has_rot[:, None]
        tops[1] = float(np.sqrt((tq * tq).sum(1).max(initial=0.0)))
    apply_wrenches(sim, pts, f, bod[0], tq)


def _clip_rows(v: np.ndarray, limit: float) -> np.ndarray:
    """``clip_norm`` of finite rows [N, 3], skipping the work when none is over ``limit``."""
    n2 = (v * v).sum(1)
    if n2.max(initial=0.0) <= limit * limit:
        return v
    return v * np.minimum(1.0, limit / np.sqrt(np.maximum(n2, 1e-24)))[:, None]


def lift_above_floor(p: np.ndarray, parents: np.ndarray, min_z: np.ndarray) -> np.ndarray:
    """Targets [J, 3] with every joint at least ``min_z`` [J] high: a joint below it swings up
    about its parent's target (bone length kept, heading kept), or is raised if that cannot reach."""
    low = p[:, 2] < min_z
    if not low.any():
        return p
    out = p.copy()
    par = np.maximum(parents, 0)
    d = p - p[par]
    L = np.sqrt((d * d).sum(1))
    dz = min_z - p[par, 2]
    hz = np.sqrt((d[:, :2] ** 2).sum(1))
    can = low & (parents >= 0) & (np.abs(dz) < L) & (hz > 1e-9)
    h = np.sqrt(np.maximum(L ** 2 - dz ** 2, 0.0)) / np.maximum(hz, 1e-9)
    swung = np.concatenate([p[par, :2] + d[:, :2] * h[:, None], (p[par, 2] + dz)[:, None]], axis=1)
    out[can] = swung[can]
    out[:, 2] = np.maximum(out[:, 2], min_z)
    return out


def set_target_into(positions, orientations, body_joints, parents, a, b0, dt, limits, min_z, tgt, rot,
                    inp) -> None:
    """:func:`.controller_kernels.set_target_into`: one character's new target into the stacked arrays."""
    p_t, v_t, _, _ = tgt
    q_t, w_t, has_rot = rot
    p_in, v_in = inp
    max_speed, max_rate = limits
    sl = slice(a, a + len(positions))
    bs = slice(b0, b0 + len(body_joints))
    p = np.asarray(positions, float)
    q = np.asarray(orientations, float)[body_joints]
    ok_p = np.isfinite(p).all(1)
    ok_q = np.isfinite(q).all(1)
    # the floor is a constraint too: no target below a capsule's radius (a target foot under
    # the floor would press the body into it with the full bounded force)
    p = np.where(ok_p[:, None], p, np.nan)
    use_dt = 1e-4 < dt < 0.5
    if use_dt:   # the input's own velocity, what foot contact is judged by
        vi = (p - p_in[sl]) / dt
        vi[~np.isfinite(vi).all(1)] = 0.0
        v_in[sl] = vi
    else:
        v_in[sl] = 0.0
    p_in[sl] = p
    p = lift_above_floor(p, parents, min_z[sl])
    if use_dt:
        # the velocity of the target the body tracks (lifted now minus lifted before): the raw
        # input minus the last lifted target adds the lift's offset / dt
        v = (p - p_t[sl]) / dt
        v[~np.isfinite(v).all(1)] = 0.0   # a joint or its previous target missing: no velocity
        v_t[sl] = _clip_rows(v, max_speed)
        # angular velocity of each target orientation: 2 vec(q q_prev^-1) / dt, small-angle
        # form (exact to 0.1 % below 6 degrees a frame; faster turns are clipped anyway)
        e = quat_multiply_conj_rows(q, q_t[bs])
        w = e[:, 1:] * np.copysign(2.0 / dt, e[:, :1])
        w = np.where((ok_q & has_rot[bs])[:, None], w, 0.0)
        w_t[bs] = _clip_rows(w, max_rate)
    else:
        v_t[sl] = 0.0
        w_t[bs] = 0.0
    p_t[sl] = p
    q_t[bs] = np.where(ok_q[:, None], q, q_t[bs])
    has_rot[bs] = ok_q


def switch_pins(inp, pins, mocap_pos, site_xpos, pt_site, eq_active, rule) -> bool:
    """:func:`.controller_kernels.switch_pins`: the foot pins switched and drawn after their targets."""
    p_in, v_in = inp
    point, rest_z, pin_on, mocap, eq = pins
    contact_height, contact_speed, pin_slack, pin_hold, follow = rule
    pt = p_in[point]   # the input's: a toe lifted out of the floor swings faster
    vt = v_in[point]
    # NaN compares False: a missing target is neither low (no pin) nor kept (lets go)
    h = pt[:, 2] - rest_z
    vt2 = (vt[:, :2] ** 2).sum(1)
    on = (h <= contact_height) & (vt2 <= contact_speed ** 2) & ~pin_on
    if on.any():   # only then where the feet are: a foot far from its target catches up first
        cur = site_xpos[pt_site[point]]
        on &= ((pt[:, :2] - cur[:, :2]) ** 2).sum(1) <= pin_slack ** 2
    off = np.zeros_like(on)
    if pin_on.any():
        anchor = mocap_pos[mocap]
        gap = pt[:, :2] - anchor[:, :2]
        drift2 = (gap ** 2).sum(1)
        keep = (h <= contact_height + 0.01) & (vt2 <= 4 * contact_speed ** 2) & (drift2 <= pin_slack ** 2)
        off = pin_on & ~keep
        pull = pin_on & keep & (drift2 > pin_hold ** 2)
        if pull.any():
            drift = np.sqrt(drift2[pull])
            g = np.minimum(follow, drift - pin_hold) / drift
            anchor[pull, :2] += g[:, None] * gap[pull]
            mocap_pos[mocap[pull]] = anchor[pull]
    if not (on.any() or off.any()):
        return False              # no pin switched: nothing more to write
    if on.any():
        at = cur[on]
        at[:, 2] = rest_z[on]     # on the floor: never hold a foot sunk into it
        mocap_pos[mocap[on]] = at
    pin_on[:] = (pin_on | on) & ~off
    eq_active[eq] = pin_on
    return True


def geom_state_into(geom_xpos, geom_xmat, site_xpos, lay, p_t, override, pos, quat, err) -> None:
    """:func:`.state_kernels.geom_state_into`: published geom poses, joint and capsule errors."""
    geom_ids, pt_site, j0, j1, point_err = lay
    target = np.where(np.isfinite(override), override, p_t)
    point_err[:] = np.linalg.norm(site_xpos[pt_site] - target, axis=1)
    pos[:] = geom_xpos[geom_ids]
    quat[:] = matrix_to_quat(geom_xmat[geom_ids].reshape(-1, 3, 3))
    mine = j0 >= 0
    err[:] = np.nan
    err[mine] = 0.5 * (point_err[j0[mine]] + point_err[j1[mine]])


def local_rotations_into(qpos, ball_adr, ball_joints, root_adr, root_joint, rest_root, out, root_pos) -> None:
    """:func:`.state_kernels.local_rotations_into`: one simulated character's local rotations."""
    out[ball_joints] = qpos[ball_adr[:, None] + np.arange(4)]
    r = root_adr
    out[root_joint] = quat_multiply(quat_conjugate(rest_root), qpos[r + 3:r + 7])
    out /= np.linalg.norm(out, axis=1, keepdims=True)
    root_pos[:] = qpos[r:r + 3]


REFERENCE = Kernels(frame_terms, substep_control, set_target_into, switch_pins, geom_state_into, local_rotations_into)


def world_orientations(local: np.ndarray, rest: np.ndarray, parents: np.ndarray, levels) -> np.ndarray:
    """World orientations [J, 4] (wxyz) of local rotations [J, 4]: W[j] = W[parent] rest[j] local[j],
    by quaternion products one depth level at a time (the character's matrix FK costs 10x more)."""
    joint = quat_multiply_rows(rest, local)
    world = np.empty_like(joint)
    world[levels[0]] = joint[levels[0]]
    for level in levels[1:]:
        world[level] = quat_multiply_rows(world[parents[level]], joint[level])
    return world


def match(db: PostureDB, positions: np.ndarray) -> tuple[int, float, np.ndarray, bool]:
    """The numpy reference of the database query: nearest posture to one world posture [J, 3] (NaN
    rows missing): (index, heading yaw rad, root origin [3] m, whether the query could be normalised)."""
    norm, yaw, origin = normalise_one(db.frame, positions)
    if norm is None:
        return -1, 0.0, np.zeros(3), False
    return rerank(db, norm), yaw, origin, True


def rerank(db: PostureDB, norm: np.ndarray) -> int:
    """The numpy reference of the search with re-ranking: the ``db.rerank`` postures nearest to a
    normalised posture [J, 3] (NaN rows missing) in the reduced space (nearest first, first of
    equals), the one nearest in the full space over its known joints (first of equals)."""
    red = db.project(norm.reshape(1, -1))[0]
    d = db._sqnorm - 2.0 * (db._reduced @ red)
    m = max(1, min(int(db.rerank), len(d)))
    cands = np.argsort(d, kind="stable")[:m]
    known = np.isfinite(norm).all(1)
    full = ((norm[known][None] - db.positions[cands][:, known]) ** 2).sum((1, 2))
    return int(cands[int(np.argmin(full))])

def posture_world(db: PostureDB, index: int, yaw: float, origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Database posture ``index`` put at ``origin`` with heading ``yaw``: positions, local rotations."""
    world = db.positions[index] @ rz_rows(yaw) + origin
    rot = db.rotations[index].copy()
    r = db.frame.root
    # (cos h, 0, 0, sin h) * root rotation, h = yaw / 2: the heading put back, in scalars
    c, s = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    w, x, y, z = rot[r].tolist()
    rot[r] = (c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w)
    return world, rot

def complete(db: PostureDB, positions: np.ndarray, rotations: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The numpy reference of :meth:`PostureDB.complete_into` (Shum & Ho's P_e and Θ_e): missing
    (non-finite) joint positions and local rotations of one posture taken from its nearest
    database posture. Returns (P_e [J, 3], Θ_e [J, 4],
    filled [J] bool, match index or -1 when the query has no root/heading to normalise by)."""
    pos = np.asarray(positions, float)
    rot = np.asarray(rotations, float)
    miss_p = ~np.isfinite(pos).all(1)
    miss_r = ~np.isfinite(rot).all(1)
    if not (miss_p.any() or miss_r.any()):
        return pos, rot, np.zeros(len(pos), bool), -1
    idx, yaw, origin, ok = match(db, pos)
    if not ok:
        return pos, rot, np.zeros(len(pos), bool), -1
    wp, wr = posture_world(db, idx, yaw, origin)
    return (np.where(miss_p[:, None], wp, pos), np.where(miss_r[:, None], wr, rot), miss_p | miss_r, idx)


class ReferenceConditioner(TargetConditioner):
    """The numpy reference of :class:`.tracker.TargetConditioner` (its counters and holding kept)."""

    def condition(self, positions: np.ndarray, local_rotations: np.ndarray, root: np.ndarray,
                  quality: np.ndarray | None = None) -> Conditioned:
        """The numpy reference of :meth:`.tracker.TargetConditioner.condition`."""
        ch = self.character
        pos = np.asarray(positions, float).reshape(ch.n_joints, 3)
        rot = np.asarray(local_rotations, float).reshape(ch.n_joints, 4)
        root = np.asarray(root, float).reshape(3)
        n2 = (rot * rot).sum(1)
        bad_rot = ~((n2 >= 0.999 ** 2) & (n2 <= 1.001 ** 2))   # |q| off 1 by over 1e-3, or not finite
        rot = np.where(bad_rot[:, None], np.nan, rot)
        ok_p = np.isfinite(pos).all(1)
        if not ok_p.any():
            return self._hold()
        if quality is not None and self.db is not None:
            unsure = np.asarray(quality) < 2
            if unsure.all():
                return self._hold()
            pos = np.where(unsure[:, None], np.nan, pos)
            rot = np.where(unsure[:, None], np.nan, rot)
            ok_p &= ~unsure
            bad_rot |= unsure
        filled = np.zeros(ch.n_joints, bool)
        match = -1
        if self.db is not None and ((~ok_p).any() or bad_rot.any()):
            t = time.thread_time() if self.profile is not None else 0.0
            pos, rot, filled, match = complete(self.db, pos, rot)
            if self.profile is not None:
                self.profile["database"] = self.profile.get("database", 0.0) + time.thread_time() - t
            self.filled_frames += bool(filled.any())
        ok_r = np.isfinite(rot).all(1)
        if not np.isfinite(root).all():
            root = pos[ch.root] if np.isfinite(pos[ch.root]).all() else None
        orient = np.full((ch.n_joints, 4), np.nan)
        if root is not None:
            # a missing rotation turns with its parent (identity) and its orientation (and those
            # below) are marked unknown
            chain_ok = ok_r.copy()
            if not chain_ok.all():  # the usual frame has every rotation: nothing to propagate
                for level in self.character._levels[1:]:
                    chain_ok[level] &= chain_ok[ch.parents[level]]
            world = world_orientations(np.where(ok_r[:, None], rot, IDENTITY), ch.rest_rotations, ch.parents,
                                       self.character._levels)
            orient = np.where(chain_ok[:, None], world, np.nan)
        out = Conditioned(np.where(np.isfinite(pos).all(1)[:, None], pos, np.nan), orient, filled, False, match)
        self.last = out
        return out
