"""Compiled per-frame controller of the physics world: Eq 1 forces, Eq 2 torques, pins, targets.

The same arithmetic as the numpy reference in :mod:`.reference` (same signatures; tests compare
them), as numba kernels that read MuJoCo's ``mjData`` arrays in place and write the body wrenches
straight into ``data.xfrc_applied``: a force ``f`` at point ``p`` on body ``b`` adds
``[f, (p - xipos[b]) x f]`` to row ``b``, which is what ``mj_applyFT`` does. Units SI (m, m/s, N,
N·m, rad), world frame Z up, quaternions wxyz. Point arrays are stacked over every character;
``pt_*`` index sites/bodies per point, ``b_*`` per controlled body.

Kernels take groups of arrays as tuples laid out as the ``NamedTuple`` classes below say (and
unpack them in that order): callers pass ``tuple(group)``, since numba types a plain tuple in its
C dispatcher but a named one in Python (measured: 4 us more a call for 18 arrays, 10 % of a frame).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import kernel_calling
from ..kinematics import quat_kernels
from ..kinematics.quat_kernels import qmul

kernel = kernel_calling(quat_kernels)   # qmul


class Sim(NamedTuple):
    """The ``mjData`` arrays the control reads and writes (views: ``mj_resetData`` keeps them)."""

    site_xpos: np.ndarray     # [nsite, 3] m
    cvel: np.ndarray          # [nbody, 6] rad/s, m/s (rotation first), about subtree_com
    subtree_com: np.ndarray   # [nbody, 3] m
    xipos: np.ndarray         # [nbody, 3] m, body centres of mass
    xquat: np.ndarray         # [nbody, 4] wxyz
    xmat: np.ndarray          # [nbody, 9] row-major
    xfrc_applied: np.ndarray  # [nbody, 6] N, N·m (written)


class Points(NamedTuple):
    """Every controlled joint point, stacked over the characters (int64 ids, float64 bounds)."""

    site: np.ndarray     # [N] MuJoCo site of the point
    body: np.ndarray     # [N] its body
    root: np.ndarray     # [N] its body's root (for subtree_com)
    bound: np.ndarray    # [N] N, Eq 1 bound


class Bodies(NamedTuple):
    """Every controlled body, stacked over the characters."""

    body: np.ndarray     # [B] MuJoCo body id
    axis: np.ndarray     # [B, 3] twist axis in the body frame, unit
    scale: np.ndarray    # [B] kg·m^2, inertia about the axis (Eq 2 gains are per unit of it)


class Targets(NamedTuple):
    """The stacked point targets [N]; written by :func:`set_target_into` (the dodge and ``reach``
    write the constraints)."""

    p_t: np.ndarray             # [N, 3] m, tracked target (lifted above the floor), NaN: none
    v_t: np.ndarray             # [N, 3] m/s, its velocity (clipped)
    override: np.ndarray        # [N, 3] m, positional constraints (reach), NaN: none
    dodge_override: np.ndarray  # [N, 3] m, the dodge's positional targets, NaN: none


class Orientations(NamedTuple):
    """The stacked body orientation targets [B]; written by :func:`set_target_into`."""

    q_t: np.ndarray             # [B, 4] wxyz, world orientation target
    w_t: np.ndarray             # [B, 3] rad/s, its angular velocity (clipped)
    has_rot: np.ndarray         # [B] bool, an orientation target is set


class Inputs(NamedTuple):
    """The input targets as given [N], what foot contact is judged by; written by :func:`set_target_into`."""

    p_in: np.ndarray            # [N, 3] m, before lifting; NaN: missing
    v_in: np.ndarray            # [N, 3] m/s, its velocity (unclipped)


class Terms(NamedTuple):
    """A frame's Eq 1 terms (from :func:`frame_terms`): f = c0 + (i + 1) slope - kp p - kd v."""

    c0: np.ndarray      # [N, 3] N
    slope: np.ndarray   # [N, 3] N per substep
    kp: np.ndarray      # [N] N/m (0 without target)
    kd: np.ndarray      # [N] N·s/m


class Pins(NamedTuple):
    """The foot pins (virtual joints): one per foot point."""

    point: np.ndarray    # [P] stacked point of the foot
    rest_z: np.ndarray   # [P] m, the foot's rest height (on the floor)
    on: np.ndarray       # [P] bool, switched on (written)
    mocap: np.ndarray    # [P] mocap body index of the pin
    eq: np.ndarray       # [P] MuJoCo equality (connect) id


@kernel
def frame_terms(tgt, kp_pt, kd_pt, span, ts, terms) -> None:
    """Per-frame Eq 1 terms: with the target moving on at its velocity between frames, the force at
    substep i is ``c0 + (i + 1) slope - kp p - kd v``. A positional constraint (override, then the
    dodge's) replaces the target and holds still; a point without a target gets zero gains.
    In: ``tgt`` (:class:`Targets`); kp_pt, kd_pt [N] (N/m, N·s/m); span = substeps * ts (s).
    Out: ``terms`` (:class:`Terms`)."""
    p_t, v_t, override, dodge_override = tgt
    c0, slope, kp, kd = terms
    for i in range(p_t.shape[0]):
        ok = True
        for c in range(3):
            t = p_t[i, c]
            if math.isfinite(override[i, c]):
                t = override[i, c]
            if math.isfinite(dodge_override[i, c]):
                t = dodge_override[i, c]
            if not math.isfinite(t):
                ok = False
        a = kp_pt[i] if ok else 0.0
        b = kd_pt[i] if ok else 0.0
        kp[i] = a
        kd[i] = b
        for c in range(3):
            t = p_t[i, c]
            v = v_t[i, c]
            if math.isfinite(override[i, c]):
                t = override[i, c]
                v = 0.0
            if math.isfinite(dodge_override[i, c]):
                t = dodge_override[i, c]
                v = 0.0
            if not ok:
                t = 0.0
                v = 0.0
            c0[i, c] = a * (t - v * span) + b * v
            slope[i, c] = a * v * ts


@kernel
def twist_torques_into(sim, bod, rot, gains, tq) -> float:
    """Eq 2 for every controlled body (``bod``: body ids, bone axes [B, 3] in the body frame): the
    twist of ``q_t q^-1`` about the world axis, torque ``clip(kp theta + kd rate)`` along it (gains
    ``(kp_rot, kd_rot, max_torque)`` times the inertia about the axis), 0 without an orientation
    target or when not finite. Writes ``tq`` [B, 3] N·m; returns the largest norm."""
    site_xpos, cvel, subtree_com, xipos, xquat, xmat, xfrc = sim
    b_body, b_axis, scale = bod
    q_t, w_t, has_rot = rot
    kp_rot, kd_rot, max_torque = gains
    top = 0.0
    for i in range(b_body.shape[0]):
        b = b_body[i]
        a0, a1, a2 = b_axis[i, 0], b_axis[i, 1], b_axis[i, 2]
        u0 = xmat[b, 0] * a0 + xmat[b, 1] * a1 + xmat[b, 2] * a2
        u1 = xmat[b, 3] * a0 + xmat[b, 4] * a1 + xmat[b, 5] * a2
        u2 = xmat[b, 6] * a0 + xmat[b, 7] * a1 + xmat[b, 8] * a2
        if not has_rot[i]:
            tq[i, 0] = 0.0
            tq[i, 1] = 0.0
            tq[i, 2] = 0.0
            continue
        aw, ax_, ay, az = q_t[i, 0], q_t[i, 1], q_t[i, 2], q_t[i, 3]
        bw, bx, by, bz = xquat[b, 0], -xquat[b, 1], -xquat[b, 2], -xquat[b, 3]
        ew, ex, ey, ez = qmul(aw, ax_, ay, az, bw, bx, by, bz)
        s = ex * u0 + ey * u1 + ez * u2
        sign = math.copysign(1.0, ew)
        theta = 2.0 * math.atan2(s * sign, ew * sign)
        rate = (w_t[i, 0] - cvel[b, 0]) * u0 + (w_t[i, 1] - cvel[b, 1]) * u1 + (w_t[i, 2] - cvel[b, 2]) * u2
        t = (kp_rot * scale[i]) * theta + (kd_rot * scale[i]) * rate
        t = min(max(t, -max_torque), max_torque)
        if not math.isfinite(t):
            t = 0.0
        tq[i, 0] = t * u0
        tq[i, 1] = t * u1
        tq[i, 2] = t * u2
        n = math.sqrt(tq[i, 0] * tq[i, 0] + tq[i, 1] * tq[i, 1] + tq[i, 2] * tq[i, 2])
        top = max(top, n)
    return top


@kernel
def joint_forces_into(sim, pts, terms, step, f) -> float:
    """Eq 1 at every joint point for substep ``step``: the point's velocity from its body's ``cvel``
    about the subtree centre of mass, ``f = c0 + (step + 1) slope - kp p - kd v``, non-finite
    components zeroed, each norm clipped to ``bound`` [N]. Writes ``f`` [N, 3] N; returns the
    largest squared norm applied."""
    site_xpos, cvel, subtree_com, xipos, xquat, xmat, xfrc = sim
    pt_site, pt_body, pt_root, bound = pts
    c0, slope, kp, kd = terms
    top2 = 0.0
    for i in range(pt_site.shape[0]):
        s, b, r = pt_site[i], pt_body[i], pt_root[i]
        px, py, pz = site_xpos[s, 0], site_xpos[s, 1], site_xpos[s, 2]
        rx, ry, rz = px - subtree_com[r, 0], py - subtree_com[r, 1], pz - subtree_com[r, 2]
        wx, wy, wz = cvel[b, 0], cvel[b, 1], cvel[b, 2]
        vx = cvel[b, 3] + (wy * rz - wz * ry)
        vy = cvel[b, 4] + (wz * rx - wx * rz)
        vz = cvel[b, 5] + (wx * ry - wy * rx)
        k = step + 1.0
        fx = (c0[i, 0] + slope[i, 0] * k) - kp[i] * px - kd[i] * vx
        fy = (c0[i, 1] + slope[i, 1] * k) - kp[i] * py - kd[i] * vy
        fz = (c0[i, 2] + slope[i, 2] * k) - kp[i] * pz - kd[i] * vz
        if not math.isfinite(fx):
            fx = 0.0
        if not math.isfinite(fy):
            fy = 0.0
        if not math.isfinite(fz):
            fz = 0.0
        n2 = fx * fx + fy * fy + fz * fz
        if n2 > bound[i] * bound[i]:
            sc = min(1.0, bound[i] / math.sqrt(max(n2, 1e-24)))
            fx *= sc
            fy *= sc
            fz *= sc
            n2 = fx * fx + fy * fy + fz * fz
        f[i, 0] = fx
        f[i, 1] = fy
        f[i, 2] = fz
        top2 = max(top2, n2)
    return top2


@kernel
def apply_wrenches(sim, pts, f, b_body, tq) -> None:
    """``xfrc_applied`` [nbody, 6] = the body torques ``tq`` on bodies ``b_body`` plus each point
    force ``f`` [N, 3] at its site: ``[f, (p - xipos[body]) x f]`` (mj_applyFT at the point)."""
    site_xpos, cvel, subtree_com, xipos, xquat, xmat, xfrc = sim
    pt_site, pt_body, pt_root, bound = pts
    xfrc[:, :] = 0.0
    for i in range(b_body.shape[0]):
        b = b_body[i]
        xfrc[b, 3] = tq[i, 0]
        xfrc[b, 4] = tq[i, 1]
        xfrc[b, 5] = tq[i, 2]
    for i in range(pt_site.shape[0]):
        s, b = pt_site[i], pt_body[i]
        ax = site_xpos[s, 0] - xipos[b, 0]
        ay = site_xpos[s, 1] - xipos[b, 1]
        az = site_xpos[s, 2] - xipos[b, 2]
        fx, fy, fz = f[i, 0], f[i, 1], f[i, 2]
        xfrc[b, 0] += fx
        xfrc[b, 1] += fy
        xfrc[b, 2] += fz
        xfrc[b, 3] += ay * fz - az * fy
        xfrc[b, 4] += az * fx - ax * fz
        xfrc[b, 5] += ax * fy - ay * fx


@kernel
def substep_control(sim, pts, bod, terms, rot, gains, step, f, tq, tops) -> None:
    """One substep's control after ``mj_step1``: Eq 2 torques on the first substep of a frame (held
    over the rest), Eq 1 forces, both summed into ``sim.xfrc_applied``. ``gains``: (kp_rot 1/s^2,
    kd_rot 1/s, max_torque N·m). Writes ``f`` [N, 3], ``tq`` [B, 3]; ``tops`` [2]: largest squared
    force of this substep, largest torque norm (first substep)."""
    if step == 0:
        tops[1] = twist_torques_into(sim, bod, rot, gains, tq)
    tops[0] = joint_forces_into(sim, pts, terms, step, f)
    apply_wrenches(sim, pts, f, bod[0], tq)


@kernel
def _orientation_targets(orientations, body_joints, b0, dt, max_rate, rot) -> None:
    """:func:`set_target_into`'s orientations: bodies from ``b0`` take their joint's orientation
    (kept where the new one is missing) and its rate, 2 vec(q q_prev^-1) / dt clipped to
    ``max_rate`` rad/s (0 without a previous one or a usable ``dt``)."""
    q_t, w_t, has_rot = rot
    use_dt = 1e-4 < dt < 0.5
    for k in range(body_joints.shape[0]):
        i = b0 + k
        j = body_joints[k]
        qw, qx, qy, qz = orientations[j, 0], orientations[j, 1], orientations[j, 2], orientations[j, 3]
        ok_q = math.isfinite(qw) and math.isfinite(qx) and math.isfinite(qy) and math.isfinite(qz)
        wx, wy, wz = 0.0, 0.0, 0.0
        if use_dt and ok_q and has_rot[i]:
            # 2 vec(q q_prev^-1) / dt, signed by its scalar part (the short way round)
            bw, bx, by, bz = q_t[i, 0], -q_t[i, 1], -q_t[i, 2], -q_t[i, 3]
            ew = qw * bw - qx * bx - qy * by - qz * bz
            ex = qw * bx + qx * bw + qy * bz - qz * by
            ey = qw * by - qx * bz + qy * bw + qz * bx
            ez = qw * bz + qx * by - qy * bx + qz * bw
            g = math.copysign(2.0 / dt, ew)
            wx, wy, wz = ex * g, ey * g, ez * g
            n2 = wx * wx + wy * wy + wz * wz
            if n2 > max_rate * max_rate:
                sc = min(1.0, max_rate / math.sqrt(max(n2, 1e-24)))
                wx *= sc
                wy *= sc
                wz *= sc
        w_t[i, 0] = wx
        w_t[i, 1] = wy
        w_t[i, 2] = wz
        if ok_q:
            q_t[i, 0] = qw
            q_t[i, 1] = qx
            q_t[i, 2] = qy
            q_t[i, 3] = qz
        has_rot[i] = ok_q


@kernel
def set_target_into(positions, orientations, body_joints, parents, a, b0, dt, limits, min_z, tgt, rot,
                    inp) -> None:
    """One character's new target into the stacked arrays (points from ``a``, bodies from ``b0``):
    a target under the floor (below ``min_z``) swung up about its parent, else raised; velocities
    of those targets by finite differences over ``dt`` s (none when ``dt`` is outside (1e-4, 0.5) s;
    a row missing now or before gets 0), clipped to ``max_speed`` m/s and ``max_rate`` rad/s;
    orientations kept where the new one is missing; ``limits`` = (max_speed, max_rate). ``inp``
    (``p_in``, ``v_in`` [N, 3]): the input rows as given (a partly missing row NaN) and their
    velocities (unclipped; 0 where not finite), what the foot pins judge contact by. The numpy
    reference is :func:`.reference.set_target_into`."""
    p_t, v_t, _, _ = tgt
    p_in, v_in = inp
    max_speed, max_rate = limits
    J = positions.shape[0]
    use_dt = 1e-4 < dt < 0.5
    for j in range(J):
        i = a + j
        # the target the body tracks: lift_above_floor on the row (a partly missing row is missing)
        px, py, pz = positions[j, 0], positions[j, 1], positions[j, 2]
        ok = math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)
        if not ok:
            px, py, pz = np.nan, np.nan, np.nan
        # the input as given and its velocity (contact is the performer's, not the lifted target's)
        ix, iy, iz = 0.0, 0.0, 0.0
        if use_dt and ok:
            ix = (px - p_in[i, 0]) / dt
            iy = (py - p_in[i, 1]) / dt
            iz = (pz - p_in[i, 2]) / dt
            if not (math.isfinite(ix) and math.isfinite(iy) and math.isfinite(iz)):
                ix, iy, iz = 0.0, 0.0, 0.0
        v_in[i, 0] = ix
        v_in[i, 1] = iy
        v_in[i, 2] = iz
        p_in[i, 0] = px
        p_in[i, 1] = py
        p_in[i, 2] = pz
        if ok:
            lo = min_z[i]
            if pz < lo:
                par = parents[j]
                q = par if par >= 0 else 0
                ux, uy, uz = positions[q, 0], positions[q, 1], positions[q, 2]
                ok_par = math.isfinite(ux) and math.isfinite(uy) and math.isfinite(uz)
                dx, dy, dzz = px - ux, py - uy, pz - uz
                L = math.sqrt(dx * dx + dy * dy + dzz * dzz)
                dz = lo - uz
                hz = math.sqrt(dx * dx + dy * dy)
                if ok_par and par >= 0 and abs(dz) < L and hz > 1e-9:
                    h = math.sqrt(max(L * L - dz * dz, 0.0)) / max(hz, 1e-9)
                    px = ux + dx * h
                    py = uy + dy * h
                    pz = uz + dz
                pz = max(pz, lo)
        # its velocity: lifted now minus lifted before (not the raw input minus the lifted target,
        # which adds the lift's offset / dt)
        vx, vy, vz = 0.0, 0.0, 0.0
        if use_dt:
            vx = (px - p_t[i, 0]) / dt
            vy = (py - p_t[i, 1]) / dt
            vz = (pz - p_t[i, 2]) / dt
            if not (math.isfinite(vx) and math.isfinite(vy) and math.isfinite(vz)):
                vx, vy, vz = 0.0, 0.0, 0.0
            n2 = vx * vx + vy * vy + vz * vz
            if n2 > max_speed * max_speed:
                sc = min(1.0, max_speed / math.sqrt(max(n2, 1e-24)))
                vx *= sc
                vy *= sc
                vz *= sc
        v_t[i, 0] = vx
        v_t[i, 1] = vy
        v_t[i, 2] = vz
        p_t[i, 0] = px
        p_t[i, 1] = py
        p_t[i, 2] = pz
    _orientation_targets(orientations, body_joints, b0, dt, max_rate, rot)


@kernel
def switch_pins(inp, pins, mocap_pos, site_xpos, pt_site, eq_active, rule) -> bool:
    """Virtual joints on the feet (Shum & Ho 6.1), judged by the input target (``p_in``, ``v_in``:
    a toe target under the floor swung up about the ankle moves faster than the toe did): a pin
    switches on where its foot's target is within
    ``contact_height`` of its rest height and slower than ``contact_speed`` horizontally, the
    simulated foot within ``pin_slack`` of it (placed where that foot is, on the floor), and off
    when the target lifts or speeds up (hysteresis: 1 cm higher, twice as fast) or jumps
    ``pin_slack`` from it. While on, a target more than ``pin_hold`` from its pin draws the pin
    after it horizontally by at most ``follow_step`` m (this frame's share of the follow speed):
    a pivoting foot turns with its target at a bounded rate instead of being let go and caught
    up at PD speed. Writes ``pin_on``, ``mocap_pos`` and ``eq_active``; True if any switched. A
    missing target (NaN) neither pins nor holds. ``rule`` = (contact_height, contact_speed,
    pin_slack, pin_hold, follow_step), m and m/s. Reference: :func:`.reference.switch_pins`."""
    p_in, v_in = inp
    pin_point, pin_rest_z, pin_on, pin_mocap, pin_eq = pins
    contact_height, contact_speed, pin_slack, pin_hold, follow_step = rule
    changed = False
    for k in range(pin_point.shape[0]):
        i = pin_point[k]
        h = p_in[i, 2] - pin_rest_z[k]
        vt2 = v_in[i, 0] * v_in[i, 0] + v_in[i, 1] * v_in[i, 1]
        m = pin_mocap[k]
        if pin_on[k]:
            dx = p_in[i, 0] - mocap_pos[m, 0]
            dy = p_in[i, 1] - mocap_pos[m, 1]
            d2 = dx * dx + dy * dy
            keep = (h <= contact_height + 0.01) and (vt2 <= 4.0 * contact_speed * contact_speed) \
                and (d2 <= pin_slack * pin_slack)
            if not keep:
                pin_on[k] = False
                changed = True
            elif d2 > pin_hold * pin_hold:
                d = math.sqrt(d2)
                g = min(follow_step, d - pin_hold) / d
                mocap_pos[m, 0] += g * dx
                mocap_pos[m, 1] += g * dy
        elif h <= contact_height and vt2 <= contact_speed * contact_speed:
            s = pt_site[i]
            dx = p_in[i, 0] - site_xpos[s, 0]
            dy = p_in[i, 1] - site_xpos[s, 1]
            if dx * dx + dy * dy <= pin_slack * pin_slack:
                mocap_pos[m, 0] = site_xpos[s, 0]
                mocap_pos[m, 1] = site_xpos[s, 1]
                mocap_pos[m, 2] = pin_rest_z[k]   # on the floor: never hold a foot sunk into it
                pin_on[k] = True
                changed = True
    if changed:
        for k in range(pin_point.shape[0]):
            eq_active[pin_eq[k]] = pin_on[k]
    return changed


def warm() -> None:
    """Compile every kernel here once on small inputs (fills the on-disk cache)."""
    n, b, nb = 2, 2, 3
    tgt = tuple(Targets(np.zeros((n, 3)), np.zeros((n, 3)), np.full((n, 3), np.nan), np.full((n, 3), np.nan)))
    rot = tuple(Orientations(np.tile([1.0, 0, 0, 0], (b, 1)), np.zeros((b, 3)), np.ones(b, dtype=np.bool_)))
    inp = tuple(Inputs(np.zeros((n, 3)), np.zeros((n, 3))))
    terms = tuple(Terms(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), np.zeros(n)))
    frame_terms(tgt, np.ones(n), np.ones(n), 0.01, 0.005, terms)
    idx = np.arange(n, dtype=np.int64)
    sim = tuple(Sim(np.zeros((nb, 3)), np.zeros((nb, 6)), np.zeros((nb, 3)), np.zeros((nb, 3)),
                    np.tile([1.0, 0, 0, 0], (nb, 1)), np.tile(np.eye(3).ravel(), (nb, 1)), np.zeros((nb, 6))))
    pts = tuple(Points(idx, idx, idx, np.ones(n)))
    bod = tuple(Bodies(idx, np.ones((b, 3)), np.ones(b)))
    substep_control(sim, pts, bod, terms, rot, (1.0, 1.0, 1.0), 0, np.zeros((n, 3)), np.zeros((b, 3)), np.zeros(2))
    set_target_into(np.zeros((n, 3)), np.tile([1.0, 0, 0, 0], (n, 1)), idx, np.array([-1, 0], dtype=np.int64),
                    0, 0, 0.01, (6.0, 20.0), np.zeros(n), tgt, rot, inp)
    pins = tuple(Pins(idx, np.zeros(n), np.zeros(n, dtype=np.bool_), idx, idx))
    switch_pins(inp, pins, np.zeros((nb, 3)), np.zeros((nb, 3)), idx, np.zeros(2, dtype=np.bool_),
                (0.03, 0.25, 0.05, 0.02, 0.0015))
