"""Compiled one-frame retargeting (numba): the arithmetic of live's frame, planting and leg IK included.

Same math as :class:`live.LiveKernel`'s numpy ``run`` (the reference, checked to 1e-12 in
the tests against the batched path), as plain loops over a frame's few dozen joints: holding
missing source values, Claro's Eq 4.1 on the source quaternions (dependencies included), bones
following the source bones, spread chains with their end point matched, aimed clavicles,
inheritance and rest orientations, root, forward kinematics, local rotations, and Kiip's foot
planting (contact from height and windowed speed, planted targets, two-bone leg IK). World frame,
Z up, metres, seconds, quaternions wxyz. Inputs and outputs are float64/int64/bool arrays that
:class:`live.CompiledFrame` preallocates; nothing here allocates per frame. The constants and the
scratch travel in one :class:`frame_plan.FramePlan`, read by name (``p.K``, ``p.parents``).

Plant state (carried between frames) is one float array ``ps`` [17]: planted l, r (0/1), anchor xy
l, r, offset xy l, r, last time (NaN: none yet), lowest ankle height l, r (NaN: none yet), the
scaled source ankle xy l, r last seen (NaN: none yet); the
speed window is ``ht`` [cap] times and ``hxy`` [cap, 4] ankle xy (l x, l y, r x, r y), ``hn[0]``
of them in use (the caller keeps cap > hn[0]).
"""
from __future__ import annotations

import math

import numpy as np

from ..jit import kernel_calling
from ..kinematics import quat_kernels
from ..kinematics.quat_kernels import qmul
from .foot_planting import MOVE_M

kernel = kernel_calling(quat_kernels)   # qmul
QUALITY_GOOD = 2


@kernel
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3, out, k):
    """out[k] = a * b (Hamilton, wxyz: :func:`quat_kernels.qmul`)."""
    out[k, 0], out[k, 1], out[k, 2], out[k, 3] = qmul(a0, a1, a2, a3, b0, b1, b2, b3)


@kernel
def _rotate(q, k, v0, v1, v2, out, m):
    """out[m] = R(q[k]) v for a unit quaternion q[k]."""
    w, x, y, z = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
    tx, ty, tz = 2.0 * (y * v2 - z * v1), 2.0 * (z * v0 - x * v2), 2.0 * (x * v1 - y * v0)
    out[m, 0] = v0 + w * tx + y * tz - z * ty
    out[m, 1] = v1 + w * ty + z * tx - x * tz
    out[m, 2] = v2 + w * tz + x * ty - y * tx


@kernel
def _source_bone(A, i, pts, a, b):
    """A[i] · (pts[b] - pts[a]): a source bone in the character's axes (the alignment A of Eq 4.1)."""
    v0 = pts[b, 0] - pts[a, 0]
    v1 = pts[b, 1] - pts[a, 1]
    v2 = pts[b, 2] - pts[a, 2]
    return (A[i, 0, 0] * v0 + A[i, 0, 1] * v1 + A[i, 0, 2] * v2,
            A[i, 1, 0] * v0 + A[i, 1, 1] * v1 + A[i, 1, 2] * v2,
            A[i, 2, 0] * v0 + A[i, 2, 1] * v1 + A[i, 2, 2] * v2)


@kernel
def _between(a0, a1, a2, b0, b1, b2, out, k):
    """out[k] = the shortest-arc unit quaternion turning direction a onto b (any lengths);
    antiparallel: a turn by pi about a x X (a x Y when a is along X), as quat_between, sign as
    matrix_to_quat gives it (largest component positive, then w >= 0)."""
    dot = a0 * b0 + a1 * b1 + a2 * b2
    ab = math.sqrt((a0 * a0 + a1 * a1 + a2 * a2) * (b0 * b0 + b1 * b1 + b2 * b2))
    w = ab + dot
    if w >= 1e-9 * ab:
        x, y, z = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    else:
        na = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        u0, u1, u2 = a0 / na, a1 / na, a2 / na
        w = 0.0
        if abs(u0) < 0.9:   # u x X
            x, y, z = 0.0, u2, -u1
        else:               # u x Y
            x, y, z = -u2, 0.0, u0
        big = x
        if abs(y) > abs(big):
            big = y
        if abs(z) > abs(big):
            big = z
        if big < 0.0:
            x, y, z = -x, -y, -z
    n = math.sqrt(w * w + x * x + y * y + z * z)
    out[k, 0], out[k, 1], out[k, 2], out[k, 3] = w / n, x / n, y / n, z / n


@kernel
def _lmul(p, i, q, j):
    """q[j] = p[i] * q[j] in place."""
    a0, a1, a2, a3 = p[i, 0], p[i, 1], p[i, 2], p[i, 3]
    _qmul(a0, a1, a2, a3, q[j, 0], q[j, 1], q[j, 2], q[j, 3], q, j)


@kernel
def hold_frame(pts_in, pok_in, rot_in, rok_in, check_norm, st_pts, st_rot, pts_seen, rot_seen, pq, rq, qn):
    """Validity and holding: a point is good when finite and flagged, a rotation when finite, flagged
    and (``check_norm``) of norm within 1e-3 of 1; bad ones take the held value (state updated in
    place). Quality [P], [R]: 2 good, 1 held, 0 never seen. ``qn`` [R, 4]: the held rotations, unit.
    Returns True when every input was good."""
    good = True
    for p in range(pts_in.shape[0]):
        x, y, z = pts_in[p, 0], pts_in[p, 1], pts_in[p, 2]
        if pok_in[p] and math.isfinite(x) and math.isfinite(y) and math.isfinite(z):
            st_pts[p, 0], st_pts[p, 1], st_pts[p, 2] = x, y, z
            pts_seen[p] = True
            pq[p] = QUALITY_GOOD
        else:
            good = False
            pq[p] = 1 if pts_seen[p] else 0
    for r in range(rot_in.shape[0]):
        w, x, y, z = rot_in[r, 0], rot_in[r, 1], rot_in[r, 2], rot_in[r, 3]
        n = math.sqrt(w * w + x * x + y * y + z * z)
        ok = rok_in[r] and (abs(n - 1.0) < 1e-3 if check_norm else math.isfinite(n))
        if ok:
            st_rot[r, 0], st_rot[r, 1], st_rot[r, 2], st_rot[r, 3] = w, x, y, z
            rot_seen[r] = True
            rq[r] = QUALITY_GOOD
        else:
            good = False
            rq[r] = 1 if rot_seen[r] else 0
            w, x, y, z = st_rot[r, 0], st_rot[r, 1], st_rot[r, 2], st_rot[r, 3]
            n = math.sqrt(w * w + x * x + y * y + z * z)
        qn[r, 0], qn[r, 1], qn[r, 2], qn[r, 3] = w / n, x / n, y / n, z / n
    return good


@kernel
def drive_frame(p, pts):
    """Per-joint deltas ``p.D`` [J + 1, 4] (row J: identity) from the held unit source rotations
    ``p.qn`` [R, 4] and points ``pts`` [P, 3] (m): Eq 4.1 (``p.K`` = A·_·D·R⁻¹·A⁻¹ as 4x4 matrices,
    dependency levels ``p.dep_idx`` with R the identity slot), following bones (``p.f_*``), spread
    chains (``p.c_*``), aims (``p.a_*``); :class:`frame_plan.FramePlan` names every field."""
    D, dq, rot_joint = p.D, p.dq, p.rot_joint
    _eq41(p)
    _follow_bones(p, pts)
    J1 = D.shape[0]
    for j in range(J1):
        D[j, 0], D[j, 1], D[j, 2], D[j, 3] = 1.0, 0.0, 0.0, 0.0
    for i in range(rot_joint.shape[0]):
        j = rot_joint[i]
        D[j, 0], D[j, 1], D[j, 2], D[j, 3] = dq[i, 0], dq[i, 1], dq[i, 2], dq[i, 3]
    _spread_chains(p, pts)
    _aim_joints(p, pts)


@kernel
def _eq41(p):
    """Eq 4.1 on the rotate joints: dq[i] = K[i] · (Q_k · the dependency rotations), from the held unit rotations qn."""
    rot_src, dep_idx, K, qn, qk, dq = p.rot_src, p.dep_idx, p.K, p.qn, p.qk, p.dq
    n = rot_src.shape[0]
    R = qn.shape[0]
    for i in range(n):
        s = rot_src[i]
        qk[i, 0], qk[i, 1], qk[i, 2], qk[i, 3] = qn[s, 0], qn[s, 1], qn[s, 2], qn[s, 3]
        for lev in range(dep_idx.shape[0]):
            d = dep_idx[lev, i]
            if d < R:
                _qmul(qk[i, 0], qk[i, 1], qk[i, 2], qk[i, 3], qn[d, 0], qn[d, 1], qn[d, 2], qn[d, 3], qk, i)
        for r in range(4):
            dq[i, r] = K[i, r, 0] * qk[i, 0] + K[i, r, 1] * qk[i, 1] + K[i, r, 2] * qk[i, 2] + K[i, r, 3] * qk[i, 3]


@kernel
def _follow_bones(p, pts):
    """Bones following the source bones: each following joint's delta dq turned so that its carried rest bone points along the source bone."""
    f_m, f_a, f_b, f_bone, f_A, dq, tmp = p.f_m, p.f_a, p.f_b, p.f_bone, p.f_A, p.dq, p.tmp
    # bones following the source bones: turn the carried bone onto the source's (A applied)
    for f in range(f_m.shape[0]):
        m = f_m[f]
        _rotate(dq, m, f_bone[f, 0], f_bone[f, 1], f_bone[f, 2], tmp, 0)
        w0, w1, w2 = _source_bone(f_A, f, pts, f_a[f], f_b[f])
        if not w0 * w0 + w1 * w1 + w2 * w2 > 1e-18:    # |want| <= 1e-9 m: nothing to follow
            w0, w1, w2 = tmp[0, 0], tmp[0, 1], tmp[0, 2]
        _between(tmp[0, 0], tmp[0, 1], tmp[0, 2], w0, w1, w2, tmp, 1)
        _lmul(tmp, 1, dq, m)


@kernel
def _spread_chains(p, pts):
    """Spread chains in D: each chain joint takes its share of the turn from start to end, then the
    chain is turned so that its end point lies on the scaled source end point."""
    c_start, c_end, c_jptr, c_joints, c_frac, c_iters = p.c_start, p.c_end, p.c_jptr, p.c_joints, p.c_frac, p.c_iters
    c_correct, c_end_src, c_pivot_src, c_A, c_pptr = p.c_correct, p.c_end_src, p.c_pivot_src, p.c_A, p.c_pptr
    c_path, c_off, D, tmp = p.c_path, p.c_off, p.D, p.tmp
    # spread chains: qs · (qs⁻¹ qe)^f per chain joint, then the chain turned onto the scaled end point
    for c in range(c_start.shape[0]):
        s, e = c_start[c], c_end[c]
        a0, a1, a2, a3 = D[s, 0], D[s, 1], D[s, 2], D[s, 3]
        _qmul(a0, -a1, -a2, -a3, D[e, 0], D[e, 1], D[e, 2], D[e, 3], tmp, 0)
        w, x, y, z = tmp[0, 0], tmp[0, 1], tmp[0, 2], tmp[0, 3]
        if w < 0.0:
            w, x, y, z = -w, -x, -y, -z
        sn = math.sqrt(x * x + y * y + z * z)
        if sn > 1e-15:
            x0, x1, x2 = x / sn, y / sn, z / sn
        else:
            x0, x1, x2 = 0.0, 0.0, 0.0
        ang = math.atan2(sn, w)
        # qs * (0, axis)
        u0 = -a1 * x0 - a2 * x1 - a3 * x2
        u1 = a0 * x0 + a2 * x2 - a3 * x1
        u2 = a0 * x1 - a1 * x2 + a3 * x0
        u3 = a0 * x2 + a1 * x1 - a2 * x0
        for k in range(c_jptr[c], c_jptr[c + 1]):
            h = c_frac[k] * ang
            ch, sh = math.cos(h), math.sin(h)
            j = c_joints[k]
            D[j, 0], D[j, 1], D[j, 2], D[j, 3] = ch * a0 + sh * u0, ch * a1 + sh * u1, ch * a2 + sh * u2, ch * a3 + sh * u3
        if c_correct[c]:
            t0, t1, t2 = _source_bone(c_A, c, pts, c_pivot_src[c], c_end_src[c])
            for _ in range(c_iters[c]):
                s0, s1, s2 = 0.0, 0.0, 0.0
                for k in range(c_pptr[c], c_pptr[c + 1]):
                    _rotate(D, c_path[k], c_off[k, 0], c_off[k, 1], c_off[k, 2], tmp, 0)
                    s0 += tmp[0, 0]
                    s1 += tmp[0, 1]
                    s2 += tmp[0, 2]
                _between(s0, s1, s2, t0, t1, t2, tmp, 1)
                for k in range(c_jptr[c], c_jptr[c + 1]):
                    _lmul(tmp, 1, D, c_joints[k])


@kernel
def _aim_joints(p, pts):
    """Aim joints in D from their parent-carried rest bones (``ap`` [aims, 4] scratch)."""
    a_joint, a_pre, a_bone, a_frm, a_to, a_A = p.a_joint, p.a_pre, p.a_bone, p.a_frm, p.a_to, p.a_A
    D, ap, tmp = p.D, p.ap, p.tmp
    # aims: every aim joint from its parent-carried rest bone (parents' deltas read before any is set)
    na = a_joint.shape[0]
    for i in range(na):
        k = a_pre[i]
        ap[i, 0], ap[i, 1], ap[i, 2], ap[i, 3] = D[k, 0], D[k, 1], D[k, 2], D[k, 3]
    for i in range(na):
        _rotate(ap, i, a_bone[i, 0], a_bone[i, 1], a_bone[i, 2], tmp, 0)
        w0, w1, w2 = _source_bone(a_A, i, pts, a_frm[i], a_to[i])
        _between(tmp[0, 0], tmp[0, 1], tmp[0, 2], w0, w1, w2, tmp, 1)
        j = a_joint[i]
        _qmul(tmp[1, 0], tmp[1, 1], tmp[1, 2], tmp[1, 3], ap[i, 0], ap[i, 1], ap[i, 2], ap[i, 3], D, j)


@kernel
def world_from_deltas(p, pts, root):
    """World orientations ``p.W`` [J, 4] = D[nearest driven] · rest world orientation; the root [3]
    (m) from the source root point: root_M (ratio, heading) times it plus root_c (floor matched,
    offset), plus R(W[root_joint]) root_s (the mid-hip rule's rest root - mid-hip in the root's frame;
    zero when off)."""
    D, src_ext, rw_q, W, root_src = p.D, p.src_ext, p.rw_q, p.W, p.root_src
    root_M, root_c, root_j, root_s = p.root_M, p.root_c, p.root_joint, p.root_s
    for j in range(W.shape[0]):
        s = src_ext[j]
        _qmul(D[s, 0], D[s, 1], D[s, 2], D[s, 3], rw_q[j, 0], rw_q[j, 1], rw_q[j, 2], rw_q[j, 3], W, j)
    p0, p1, p2 = pts[root_src, 0], pts[root_src, 1], pts[root_src, 2]
    for r in range(3):
        root[r] = root_M[r, 0] * p0 + root_M[r, 1] * p1 + root_M[r, 2] * p2 + root_c[r]
    v0, v1, v2 = root_s[0], root_s[1], root_s[2]
    if v0 != 0.0 or v1 != 0.0 or v2 != 0.0:
        w, x, y, z = W[root_j, 0], W[root_j, 1], W[root_j, 2], W[root_j, 3]
        tx, ty, tz = 2.0 * (y * v2 - z * v1), 2.0 * (z * v0 - x * v2), 2.0 * (x * v1 - y * v0)
        root[0] += v0 + w * tx + y * tz - z * ty
        root[1] += v1 + w * ty + z * tx - x * tz
        root[2] += v2 + w * tz + x * ty - y * tx


@kernel
def pose_from_world(plan, root, pos, local):
    """Joint positions [J, 3] (root + parent-rotated rest offsets down the hierarchy, ``order`` parents
    first) and local rotations [J, 4] rest_local⁻¹ · W[parent]⁻¹ · W with w >= 0, from ``plan.W``."""
    W, parents, order, offsets, rl_inv, tmp = plan.W, plan.parents, plan.order, plan.offsets, plan.rl_inv, plan.tmp
    for k in range(order.shape[0]):
        j = order[k]
        p = parents[j]
        if p < 0:
            pos[j, 0], pos[j, 1], pos[j, 2] = root[0], root[1], root[2]
            a0, a1, a2, a3 = 1.0, 0.0, 0.0, 0.0
        else:
            _rotate(W, p, offsets[j, 0], offsets[j, 1], offsets[j, 2], tmp, 0)
            pos[j, 0] = pos[p, 0] + tmp[0, 0]
            pos[j, 1] = pos[p, 1] + tmp[0, 1]
            pos[j, 2] = pos[p, 2] + tmp[0, 2]
            a0, a1, a2, a3 = W[p, 0], -W[p, 1], -W[p, 2], -W[p, 3]
        _qmul(a0, a1, a2, a3, W[j, 0], W[j, 1], W[j, 2], W[j, 3], tmp, 1)
        _qmul(rl_inv[j, 0], rl_inv[j, 1], rl_inv[j, 2], rl_inv[j, 3], tmp[1, 0], tmp[1, 1], tmp[1, 2], tmp[1, 3],
              local, j)
        if local[j, 0] < 0.0:
            local[j, 0], local[j, 1], local[j, 2], local[j, 3] = -local[j, 0], -local[j, 1], -local[j, 2], -local[j, 3]


@kernel
def _speeds(ht, hxy, hn, t, x_l, y_l, x_r, y_r, window_s, speed):
    """foot_planting._speed_one: append (t, xy) to the window, drop samples older than ``window_s``
    (at least two kept), least-squares horizontal speed per foot (0 with fewer than two finite)."""
    if hn[0] >= ht.shape[0]:   # no room (the caller grows the buffers first): drop the oldest sample
        for k in range(1, hn[0]):
            ht[k - 1] = ht[k]
            for c in range(4):
                hxy[k - 1, c] = hxy[k, c]
        hn[0] -= 1
    N = hn[0] + 1
    ht[N - 1] = t
    hxy[N - 1, 0], hxy[N - 1, 1], hxy[N - 1, 2], hxy[N - 1, 3] = x_l, y_l, x_r, y_r
    lo = t - window_s - 1e-12
    first = N
    for k in range(N):
        if ht[k] >= lo:
            first = k
            break
    first = min(first, max(N - 2, 0))
    if first > 0:
        for k in range(first, N):
            ht[k - first] = ht[k]
            for c in range(4):
                hxy[k - first, c] = hxy[k, c]
        N -= first
    hn[0] = N
    speed[0], speed[1] = 0.0, 0.0
    if N < 2:
        return
    for i in range(2):
        cx, cy = 2 * i, 2 * i + 1
        cnt = 0
        st, sx, sy = 0.0, 0.0, 0.0
        for k in range(N):
            if hxy[k, cx] == hxy[k, cx] and hxy[k, cy] == hxy[k, cy]:
                cnt += 1
                st += ht[k] - t
                sx += hxy[k, cx]
                sy += hxy[k, cy]
        if cnt < 2:
            continue
        tm, xm, ym = st / cnt, sx / cnt, sy / cnt
        den, nx, ny = 0.0, 0.0, 0.0
        for k in range(N):
            if hxy[k, cx] == hxy[k, cx] and hxy[k, cy] == hxy[k, cy]:
                a = ht[k] - t - tm
                den += a * a
        if den > 1e-18:
            for k in range(N):
                if hxy[k, cx] == hxy[k, cx] and hxy[k, cy] == hxy[k, cy]:
                    a = ht[k] - t - tm
                    nx += a * (hxy[k, cx] - xm)
                    ny += a * (hxy[k, cy] - ym)
            vx, vy = nx / den, ny / den
            speed[i] = math.sqrt(vx * vx + vy * vy)


@kernel
def _follow(ps, i, sx, sy, planted):
    """foot_planting._follow on the state ``ps``: foot i's anchor moves by the source ankle's step."""
    if not (sx == sx and sy == sy):
        return
    if planted and ps[13 + 2 * i] == ps[13 + 2 * i]:
        ps[2 + 2 * i] += sx - ps[13 + 2 * i]
        ps[3 + 2 * i] += sy - ps[14 + 2 * i]
    ps[13 + 2 * i], ps[14 + 2 * i] = sx, sy


@kernel
def plant_feet(ankle, toe_z, has_toe, rest_h, toe_h, t, params, state, target, contact, speed, src_xy):
    """foot_planting.plant_one on arrays: ankles [2, 3] (m), toe heights [2] (m) -> targets [2, 3]
    and contact [2]; ``params`` = floor_z, height_m, speed_mps, release_s, window_s (m, m/s, s);
    the plant ``state`` = ps, ht, hxy, hn (module docstring) updated in place; ``speed`` [2] scratch;
    ``src_xy`` [2, 2] the scaled source ankles (m, NaN: none) a plant moves with."""
    floor_z, height_m, speed_mps, release_s, window_s = params
    ps, ht, hxy, hn = state
    nan = np.nan
    ok0 = math.isfinite(ankle[0, 0]) and math.isfinite(ankle[0, 1]) and math.isfinite(ankle[0, 2])
    ok1 = math.isfinite(ankle[1, 0]) and math.isfinite(ankle[1, 1]) and math.isfinite(ankle[1, 2])
    _speeds(ht, hxy, hn, t, ankle[0, 0] if ok0 else nan, ankle[0, 1] if ok0 else nan,
            ankle[1, 0] if ok1 else nan, ankle[1, 1] if ok1 else nan, window_s, speed)
    t_prev = ps[10]
    dt = t - t_prev if t_prev == t_prev else nan
    decay = max(0.0, 1.0 - dt / release_s) if release_s > 0 and dt == dt else 0.0
    for i in range(2):
        target[i, 0], target[i, 1], target[i, 2] = ankle[i, 0], ankle[i, 1], ankle[i, 2]
        contact[i] = False
        if not (ok0 if i == 0 else ok1):
            ps[i] = 0.0
            _follow(ps, i, src_xy[i, 0], src_xy[i, 1], False)
            continue
        h_rest = ankle[i, 2] - (floor_z + rest_h[i])
        if not ps[11 + i] <= h_rest:      # fmin: a NaN low is none yet
            ps[11 + i] = h_rest
        h = h_rest - max(ps[11 + i], 0.0)
        enter = h < height_m and speed[i] < speed_mps
        keep = h < 1.5 * height_m and speed[i] < 2.0 * speed_mps
        planted = ps[i] != 0.0
        c = enter or (planted and keep)
        x, y = ankle[i, 0], ankle[i, 1]
        _follow(ps, i, src_xy[i, 0], src_xy[i, 1], c and planted)
        if c:
            if not planted:   # begins where the foot is drawn now (a fading offset included): no jump
                ps[2 + 2 * i] = x + (ps[6 + 2 * i] if dt == dt else 0.0)
                ps[3 + 2 * i] = y + (ps[7 + 2 * i] if dt == dt else 0.0)
            ps[6 + 2 * i] = ps[2 + 2 * i] - x
            ps[7 + 2 * i] = ps[3 + 2 * i] - y
            target[i, 0], target[i, 1] = ps[2 + 2 * i], ps[3 + 2 * i]
        else:                 # released: the last offset fades out over release_s
            ps[6 + 2 * i] *= decay
            ps[7 + 2 * i] *= decay
            target[i, 0], target[i, 1] = x + ps[6 + 2 * i], y + ps[7 + 2 * i]
        contact[i] = c
        ps[i] = 1.0 if c else 0.0
        z = max(ankle[i, 2], floor_z + rest_h[i])
        if has_toe:
            lift = floor_z + toe_h[i] - toe_z[i]
            if lift != lift:
                lift = 0.0
            z = max(z, ankle[i, 2] + max(lift, 0.0))
        target[i, 2] = z
    ps[10] = t


@kernel
def _leg_ik(hip, knee, ankle, target, l1, l2, p0, p1, p2, out, k1, k2):
    """foot_planting.two_bone_ik for one leg (points [3]): out[k1] the thigh turn, out[k2] the shin
    turn (about the new knee), the knee kept in the leg's bend plane (pole p where it is straight)."""
    to0, to1, to2 = target[0] - hip[0], target[1] - hip[1], target[2] - hip[2]
    dist = math.sqrt(to0 * to0 + to1 * to1 + to2 * to2)
    dd = max(dist, 1e-12)
    u0, u1, u2 = to0 / dd, to1 / dd, to2 / dd
    d = min(max(dist, abs(l1 - l2) + 1e-6), l1 + l2 - 1e-6)
    cos_a = min(max((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1.0), 1.0)
    sin_a = math.sqrt(1.0 - cos_a * cos_a)
    k0, kk1, kk2 = knee[0] - hip[0], knee[1] - hip[1], knee[2] - hip[2]
    ku = k0 * u0 + kk1 * u1 + kk2 * u2
    v0, v1, v2 = k0 - ku * u0, kk1 - ku * u1, kk2 - ku * u2
    if not math.sqrt(v0 * v0 + v1 * v1 + v2 * v2) > 1e-6 * l1:
        pu = p0 * u0 + p1 * u1 + p2 * u2
        v0, v1, v2 = p0 - pu * u0, p1 - pu * u1, p2 - pu * u2
    vn = max(math.sqrt(v0 * v0 + v1 * v1 + v2 * v2), 1e-12)
    n0 = hip[0] + l1 * (cos_a * u0 + sin_a * v0 / vn)
    n1 = hip[1] + l1 * (cos_a * u1 + sin_a * v1 / vn)
    n2 = hip[2] + l1 * (cos_a * u2 + sin_a * v2 / vn)
    _between(k0, kk1, kk2, n0 - hip[0], n1 - hip[1], n2 - hip[2], out, k1)
    _rotate(out, k1, ankle[0] - knee[0], ankle[1] - knee[1], ankle[2] - knee[2], out, k2)   # shin after
    s0, s1, s2 = out[k2, 0], out[k2, 1], out[k2, 2]
    _between(s0, s1, s2, hip[0] + d * u0 - n0, hip[1] + d * u1 - n1, hip[2] + d * u2 - n2, out, k2)


@kernel
def legs_to_targets(p, pos):
    """Two-bone IK for each leg whose ankle is not at its target ``p.target`` [2, 3] (1e-12 m): the
    thigh turn (and the shin turn after it) applied to the world orientations ``p.W`` [J, 4] of the
    joints they carry (``p.aff``, ``p.which``: 0/1 thigh l/r, 2/3 shin l/r). Returns True when a leg moved."""
    W, target, hip, knee, ankle, l1, l2 = p.W, p.target, p.hip, p.knee, p.ankle, p.l1, p.l2
    aff, which, turns = p.aff, p.which, p.turns
    moved = False
    for t in range(4):
        turns[t, 0], turns[t, 1], turns[t, 2], turns[t, 3] = 1.0, 0.0, 0.0, 0.0
    for i in range(2):
        a = ankle[i]
        g = abs(target[i, 0] - pos[a, 0])     # Python's max over the three: a NaN first stays, later ones lose
        for c in range(1, 3):
            dv = abs(target[i, c] - pos[a, c])
            if dv > g:
                g = dv
        if not g >= MOVE_M:
            continue
        moved = True
        h = hip[i]
        w, x, y, z = W[h, 0], W[h, 1], W[h, 2], W[h, 3]   # the thigh's forward axis as the pole
        _leg_ik(pos[h], pos[knee[i]], pos[a], target[i], l1[i], l2[i],
                1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y), turns, i, 2 + i)
        # the shin: the thigh's turn, then its own
        _qmul(turns[2 + i, 0], turns[2 + i, 1], turns[2 + i, 2], turns[2 + i, 3],
              turns[i, 0], turns[i, 1], turns[i, 2], turns[i, 3], turns, 2 + i)
    if moved:
        for k in range(aff.shape[0]):
            _lmul(turns, which[k], W, aff[k])
    return moved


@kernel
def plant_frame(p, pos, root, local, t, state, contact, pts):
    """Foot planting for one frame at ``t`` s: contact [2] and targets (:func:`plant_feet`, moving
    with the held source points ``pts`` [P, 3] of the ankles), leg IK (:func:`legs_to_targets`) and,
    when a leg moved, positions [J, 3] and local rotations [J, 4] anew from the root [3]; ``state``
    as :func:`plant_feet`'s."""
    ank, toe_z, ankle, toe, sxy = p.ank, p.toe_z, p.ankle, p.toe, p.src_xy
    for i in range(2):
        a = ankle[i]
        ank[i, 0], ank[i, 1], ank[i, 2] = pos[a, 0], pos[a, 1], pos[a, 2]
        toe_z[i] = pos[toe[i], 2] if p.has_toe else 0.0
        s = p.src_ankle[i]
        sxy[i, 0] = p.src_scale * pts[s, 0] if s >= 0 else np.nan
        sxy[i, 1] = p.src_scale * pts[s, 1] if s >= 0 else np.nan
    plant_feet(ank, toe_z, p.has_toe, p.rest_h, p.toe_h, t,
               (p.floor_z, p.height_m, p.speed_mps, p.release_s, p.window_s), state, p.target, contact, p.speed,
               sxy)
    if legs_to_targets(p, pos):
        pose_from_world(p, root, pos, local)


@kernel
def flag_unfollowed(pos, pts, joint, child, a, b, A, cos_limit, quality):
    """:func:`bone_follow.unfollowed` for one frame: joint positions [J, 3] and source points [P, 3]
    (m); per checked bone [B] the owner and child joints, source points a -> b, A [B, 3, 3] and
    cos_limit (see bone_follow.BoneChecks). Lowers quality [J] (int8, in place) to 1 (estimated)
    for a joint with a bone beyond its limit; returns how many joints it lowered."""
    lowered = 0
    for i in range(joint.shape[0]):
        j, k = joint[i], child[i]
        c0, c1, c2 = pos[k, 0] - pos[j, 0], pos[k, 1] - pos[j, 1], pos[k, 2] - pos[j, 2]
        d0, d1, d2 = pts[b[i], 0] - pts[a[i], 0], pts[b[i], 1] - pts[a[i], 1], pts[b[i], 2] - pts[a[i], 2]
        s0 = A[i, 0, 0] * d0 + A[i, 0, 1] * d1 + A[i, 0, 2] * d2
        s1 = A[i, 1, 0] * d0 + A[i, 1, 1] * d1 + A[i, 1, 2] * d2
        s2 = A[i, 2, 0] * d0 + A[i, 2, 1] * d1 + A[i, 2, 2] * d2
        n = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2) * np.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
        if n > 0.0 and c0 * s0 + c1 * s1 + c2 * s2 < cos_limit[i] * n and quality[j] > 1:
            quality[j] = 1
            lowered += 1
    return lowered


@kernel
def optical_frame(joint_positions, joint_quality, hips, pts, ok):
    """source.OpticalFrames.frame: points [J + 1, 3] (the joints, then the pelvis, the mean
    of the hips) and masks [J + 1] (quality >= 1; the pelvis when every hip is)."""
    J = joint_positions.shape[0]
    for j in range(J):
        pts[j, 0], pts[j, 1], pts[j, 2] = joint_positions[j, 0], joint_positions[j, 1], joint_positions[j, 2]
        ok[j] = joint_quality[j] >= 1
    x, y, z = 0.0, 0.0, 0.0
    good = True
    for h in hips:
        x += joint_positions[h, 0]
        y += joint_positions[h, 1]
        z += joint_positions[h, 2]
        good = good and ok[h]
    n = hips.shape[0]
    pts[J, 0], pts[J, 1], pts[J, 2] = x / n, y / n, z / n
    ok[J] = good


@kernel
def retarget_frame(pts, pok, rot, rok, t, held, plant, p, out):
    """One whole frame (hold, drive, world, root, pose, plant) of points [P, 3], their mask [P],
    rotations [R, 4], their mask [R] at ``t`` s. ``held`` = st_pts, st_rot, pts_seen, rot_seen (the
    retargeter's state, updated), pq, rq (this frame's source quality, written); ``plant`` = ps,
    ht, hxy, hn (the plant state); ``p`` the retargeter's :class:`frame_plan.FramePlan` (constants
    and scratch); writes ``out`` = root [3], pos [J, 3], local [J, 4], contact [2]; returns True
    when every input was good."""
    st_pts, st_rot, pts_seen, rot_seen, pq, rq = held
    root, pos, local, contact = out
    good = hold_frame(pts, pok, rot, rok, p.check_norm, st_pts, st_rot, pts_seen, rot_seen, pq, rq, p.qn)
    drive_frame(p, st_pts)
    world_from_deltas(p, st_pts, root)
    pose_from_world(p, root, pos, local)
    contact[0], contact[1] = False, False
    if p.has_legs:
        plant_frame(p, pos, root, local, t, plant, contact, st_pts)
    return good


@kernel
def retarget_actor_frame(jp, jq, rot, lq, t, held, plant, p, out):
    """A solved actor's frame (ActorPose's arrays: joints jp [J, 3] m, their quality jq [J], limb
    rotations rot [R, 4] wxyz, their quality lq [R], int8) in one call: optical_frame's points and
    masks (the pelvis last, into the plan's scratch), the limbs of quality >= 1, :func:`retarget_frame`,
    and when every input was good the joint quality [1, J] (good, bones the character could not
    follow flagged by :func:`flag_unfollowed`). ``held``, ``plant`` and ``p`` as :func:`retarget_frame`'s;
    ``out`` = root, pos, local, contact, quality, [1, ...] as RetargetResult holds them. Returns 1
    when every input was good (else 0: ``quality`` is left for the caller, which derives it from
    ``pq`` and ``rq``), plus 2 when the speed window has room for one more frame only (the caller
    grows it before the next: numpy scalars would cost it more there)."""
    root, pos, local, contact, quality = out
    st_pts = held[0]
    pts, pok, rok = p.pin, p.pin_ok, p.rot_ok
    optical_frame(jp, jq, p.hips, pts, pok)
    for r in range(rot.shape[0]):
        rok[r] = lq[r] >= 1
    good = retarget_frame(pts, pok, rot, rok, t, held, plant, p, (root[0], pos[0], local[0], contact[0]))
    if good:
        q = quality[0]
        q[:] = QUALITY_GOOD
        flag_unfollowed(pos[0], st_pts, p.b_joint, p.b_child, p.b_a, p.b_b, p.b_A, p.b_cos, q)
    ht, hn = plant[1], plant[3]
    return (1 if good else 0) + (2 if hn[0] + 2 >= ht.shape[0] else 0)


def load() -> None:
    """Load the cached machine code of the frame kernels for the live path's argument types (a node
    calls it before it reports ready, so that its first frame does not wait ~0.4 s for it)."""
    import numba

    from .frame_plan import FRAME_PLAN
    ty = lambda *xs: tuple(numba.typeof(x) for x in xs)   # noqa: E731
    f2, f1, b1 = np.zeros((1, 3)), np.zeros(1), np.zeros(1, np.bool_)
    f3, b2, i8_2 = np.zeros((1, 1, 3)), np.zeros((1, 1), np.bool_), np.zeros((1, 1), np.int8)
    i8, i64 = np.zeros(1, np.int8), np.zeros(1, np.int64)
    held, plant = (f2, f2, b1, b1, i8, i8), (f1, f1, f2, i64)
    retarget_frame.compile(ty(f2, b1, f2, b1, 0.0, held, plant) + (FRAME_PLAN,) + ty((f1, f2, f2, b1)))
    flag_unfollowed.compile(ty(f2, f2, i64, i64, i64, i64, f3, f1, i8))
    ro2, ro8 = f2.copy(), i8.copy()
    ro2.flags.writeable = ro8.flags.writeable = False
    for jp, jq in ((ro2, ro8), (f2, i8)):   # decoded (read-only) frames and plain arrays
        optical_frame.compile(ty(jp, jq, i64, f2, b1))
        retarget_actor_frame.compile(ty(jp, jq, jp, jq, 0.0, held, plant) + (FRAME_PLAN,) + ty((f2, f3, f3, b2, i8_2)))
