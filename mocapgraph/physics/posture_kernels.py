"""Compiled per-frame posture database path and target conditioning (Shum & Ho section 5).

The numpy references are :func:`.reference.complete` (normalise the query by its root
and heading, missing joints take the database mean, PCA projection, nearest posture, P_e / Θ_e
substituted from the match put back at the query's root and heading) and
:class:`.reference.ReferenceConditioner` (rotation checks, quality, world orientations by
forward kinematics), of :class:`.tracker.TargetConditioner`; tests compare them. Groups of arrays travel as
plain tuples laid out as :class:`DBArrays` and :class:`Skeleton`. Units m, rad; world Z up; quaternions wxyz.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from ..jit import kernel_calling, readonly
from ..kinematics import quat_kernels
from ..kinematics.quat_kernels import qmul

kernel = kernel_calling(quat_kernels)   # qmul


class DBArrays(NamedTuple):
    """A posture database as the kernels read it (passed as ``tuple(arrays)``: numba types a plain
    tuple in its C dispatcher, a named one in Python, 4 us more a call)."""

    pair_l: np.ndarray     # [P] left joint of each heading pair
    pair_r: np.ndarray     # [P] right joint
    root: int              # the root joint
    mean: np.ndarray       # [3J] m, mean normalised posture
    basis: np.ndarray      # [k, 3J] principal axes
    reduced_t: np.ndarray  # [k, N] the postures in the reduced space, as columns
    sqnorm: np.ndarray     # [N] their squared norms
    dist: np.ndarray       # [N] scratch
    db_pos: np.ndarray     # [N, J, 3] m, normalised postures
    db_rot: np.ndarray     # [N, J, 4] wxyz local rotations (the root's without heading)
    q: np.ndarray          # [k] scratch: the query's reduced coordinates
    info: np.ndarray       # [4] scratch: the query's (yaw rad, origin xyz m)
    cands: np.ndarray      # [m] int64 scratch: the m nearest in the reduced space, re-ranked in full


class Skeleton(NamedTuple):
    """One character's hierarchy as :func:`orient` reads it."""

    root: int              # root joint
    order: np.ndarray      # [J] joints, parents first
    parents: np.ndarray    # [J] parent joint, -1 at the root
    rest: np.ndarray       # [J, 4] wxyz rest rotations


@kernel
def query(pos, dba) -> bool:
    """One posture [J, 3] (NaN rows missing) to its reduced PCA coordinates ``q`` [k]: origin at
    the root (else the first complete left/right pair's midpoint), heading from the first complete
    pair turned to zero, missing coordinates taking ``mean`` [3J] (``dba``: :class:`DBArrays`).
    ``info`` [4] gets (yaw rad, origin xyz m). False when no pair is complete (no heading)."""
    pair_l, pair_r, root, mean, basis, _, _, _, _, _, q, info, _ = dba
    found = -1
    for p in range(pair_l.shape[0]):
        l, r = pair_l[p], pair_r[p]
        ok = True
        for c in range(3):
            if not (math.isfinite(pos[l, c]) and math.isfinite(pos[r, c])):
                ok = False
        if ok:
            found = p
            break
    if found < 0:
        return False
    l, r = pair_l[found], pair_r[found]
    yaw = math.atan2(-(pos[l, 0] - pos[r, 0]), pos[l, 1] - pos[r, 1])   # left along +Y: heading +X
    ox, oy, oz = pos[root, 0], pos[root, 1], pos[root, 2]
    if not (math.isfinite(ox) and math.isfinite(oy) and math.isfinite(oz)):
        ox = 0.5 * (pos[l, 0] + pos[r, 0])
        oy = 0.5 * (pos[l, 1] + pos[r, 1])
        oz = 0.5 * (pos[l, 2] + pos[r, 2])
    info[0], info[1], info[2], info[3] = yaw, ox, oy, oz
    # rows times the turn by -yaw about +Z (posture_db._rz_rows(-yaw))
    c, s = math.cos(-yaw), math.sin(-yaw)
    k = basis.shape[0]
    for a in range(k):
        q[a] = 0.0
    for j in range(pos.shape[0]):
        dx, dy, dz = pos[j, 0] - ox, pos[j, 1] - oy, pos[j, 2] - oz
        if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
            continue   # a missing joint takes the mean: x - mean = 0 (a partly missing row is missing)
        e0 = (dx * c + dy * -s) - mean[3 * j]
        e1 = (dx * s + dy * c) - mean[3 * j + 1]
        e2 = dz - mean[3 * j + 2]
        for a in range(k):
            q[a] += e0 * basis[a, 3 * j] + e1 * basis[a, 3 * j + 1] + e2 * basis[a, 3 * j + 2]
    return True


@kernel
def nearest(q, reduced_t, sqnorm, dist) -> int:
    """Index of the posture nearest to ``q`` [k] among ``reduced_t`` [k, N] (the reduced postures as
    columns, so the loop over postures vectorises): brute force on the squared distance less |q|^2
    (``sqnorm`` [N] = |r|^2), first of equals; ``dist`` [N] is scratch."""
    N = reduced_t.shape[1]
    for n in range(N):
        dist[n] = sqnorm[n]
    for a in range(q.shape[0]):
        m = -2.0 * q[a]
        for n in range(N):
            dist[n] += m * reduced_t[a, n]
    best = np.inf
    at = -1
    for n in range(N):
        if dist[n] < best:
            best = dist[n]
            at = n
    return at


@kernel
def nearest_m(q, reduced_t, sqnorm, dist, cands) -> int:
    """The ``m = len(cands)`` postures nearest to ``q`` [k] in the reduced space, nearest first
    (first of equals), into ``cands``; returns how many (m, or N when fewer). One pass over the
    distances (as :func:`nearest`'s) keeping the m best in order; ``dist`` is scratch."""
    N = reduced_t.shape[1]
    for n in range(N):
        dist[n] = sqnorm[n]
    for a in range(q.shape[0]):
        w = -2.0 * q[a]
        for n in range(N):
            dist[n] += w * reduced_t[a, n]
    m = min(cands.shape[0], N)
    count = 0
    for n in range(N):
        d = dist[n]
        if count == m and not d < dist[cands[m - 1]]:
            continue
        at = count if count < m else m - 1
        while at > 0 and d < dist[cands[at - 1]]:   # after its equals: first of equals stays first
            if at < m:
                cands[at] = cands[at - 1]
            at -= 1
        cands[at] = n
        if count < m:
            count += 1
    return count


@kernel
def best_full(pos, dba, count) -> int:
    """Of the first ``count`` candidates (``cands``), the posture nearest to the query ``pos`` [J, 3]
    in the full space over its known joints (normalised by ``info`` from :func:`query`: the sum of
    squared differences, Shum & Ho's Eq 5 on what is seen); first of equals, so the reduced
    space's nearest wins a tie."""
    db_pos, info, cands = dba[8], dba[11], dba[12]
    yaw, ox, oy, oz = info[0], info[1], info[2], info[3]
    c, s = math.cos(-yaw), math.sin(-yaw)
    best = np.inf
    at = cands[0]
    for t in range(count):
        n = cands[t]
        d = 0.0
        for j in range(pos.shape[0]):
            dx, dy, dz = pos[j, 0] - ox, pos[j, 1] - oy, pos[j, 2] - oz
            if not (math.isfinite(dx) and math.isfinite(dy) and math.isfinite(dz)):
                continue
            e0 = (dx * c + dy * -s) - db_pos[n, j, 0]
            e1 = (dx * s + dy * c) - db_pos[n, j, 1]
            e2 = dz - db_pos[n, j, 2]
            d += e0 * e0 + e1 * e1 + e2 * e2
        if d < best:
            best = d
            at = n
    return at


@kernel
def fill(index, dba, pos, rot, filled) -> None:
    """Missing rows (non-finite) of ``pos`` [J, 3] and ``rot`` [J, 4] taken, in place, from database
    posture ``index`` put at the query's origin and heading (``info`` from :func:`query`); the
    root's rotation gets the heading back. ``filled`` [J] marks the rows taken."""
    _, _, root, _, _, _, _, _, db_pos, db_rot, _, info, _ = dba
    yaw, ox, oy, oz = info[0], info[1], info[2], info[3]
    c, s = math.cos(yaw), math.sin(yaw)
    hc, hs = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    for j in range(pos.shape[0]):
        miss_p = not (math.isfinite(pos[j, 0]) and math.isfinite(pos[j, 1]) and math.isfinite(pos[j, 2]))
        miss_r = not (math.isfinite(rot[j, 0]) and math.isfinite(rot[j, 1]) and math.isfinite(rot[j, 2])
                      and math.isfinite(rot[j, 3]))
        filled[j] = miss_p or miss_r
        if miss_p:
            x, y, z = db_pos[index, j, 0], db_pos[index, j, 1], db_pos[index, j, 2]
            pos[j, 0] = (x * c + y * -s) + ox
            pos[j, 1] = (x * s + y * c) + oy
            pos[j, 2] = z + oz
        if miss_r:
            w, x, y, z = db_rot[index, j, 0], db_rot[index, j, 1], db_rot[index, j, 2], db_rot[index, j, 3]
            if j == root:   # (cos h, 0, 0, sin h) * root rotation, h = yaw / 2
                w, x, y, z = hc * w - hs * z, hc * x - hs * y, hc * y + hs * x, hc * z + hs * w
            rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3] = w, x, y, z


@kernel
def complete_brute(pos, rot, dba, filled) -> int:
    """:func:`query`, :func:`nearest_m`, :func:`best_full` and :func:`fill` in one call (the
    brute-force search, its m nearest re-ranked in the full space): the match index, or -1 when the
    query cannot be normalised (nothing filled)."""
    if not query(pos, dba):
        filled[:] = False
        return -1
    count = nearest_m(dba[10], dba[5], dba[6], dba[7], dba[12])   # q, reduced_t, sqnorm, dist, cands
    idx = best_full(pos, dba, count)
    fill(idx, dba, pos, rot, filled)
    return idx


@kernel
def clean(pos_in, rot_in, quality, use_quality, pos, rot) -> int:
    """A frame's input checked into ``pos`` [J, 3] and ``rot`` [J, 4]: rotations whose norm is off 1
    by over 1e-3 (or not finite) are missing; with ``use_quality`` joints below good (2) are missing
    too. Returns -1 when nothing is usable (hold the last target), 1 when some joint is missing,
    0 when the frame is complete."""
    J = pos_in.shape[0]
    any_p = False
    all_unsure = use_quality
    missing = False
    for j in range(J):
        unsure = use_quality and quality[j] < 2
        if not unsure:
            all_unsure = False
        okp = math.isfinite(pos_in[j, 0]) and math.isfinite(pos_in[j, 1]) and math.isfinite(pos_in[j, 2])
        if okp:
            any_p = True
        n2 = 0.0
        for c in range(4):
            n2 += rot_in[j, c] * rot_in[j, c]
        okr = n2 >= 0.999 ** 2 and n2 <= 1.001 ** 2
        for c in range(3):
            pos[j, c] = np.nan if unsure else pos_in[j, c]
        for c in range(4):
            rot[j, c] = rot_in[j, c] if okr and not unsure else np.nan
        if unsure or not okp or not okr:
            missing = True
    if not any_p or (use_quality and all_unsure):
        return -1
    return 1 if missing else 0


@kernel
def orient(pos, rot, root_in, skel, orient_out) -> None:
    """World orientations [J, 4] of local rotations ``rot`` (``W[j] = W[parent] (rest[j] rot[j])``,
    joints in ``order``, parents first): a missing rotation turns as identity and marks its
    orientation and those below it unknown (NaN); all unknown without a root position (neither
    ``root_in`` [3] nor joint ``root`` of ``pos`` finite; ``skel``: :class:`Skeleton`). Rows of
    ``pos`` not wholly finite become NaN."""
    root, order, parents, rest = skel
    J = pos.shape[0]
    root_ok = (math.isfinite(root_in[0]) and math.isfinite(root_in[1]) and math.isfinite(root_in[2])) or \
        (math.isfinite(pos[root, 0]) and math.isfinite(pos[root, 1]) and math.isfinite(pos[root, 2]))
    for j in range(J):
        if not (math.isfinite(pos[j, 0]) and math.isfinite(pos[j, 1]) and math.isfinite(pos[j, 2])):
            pos[j, 0] = np.nan
            pos[j, 1] = np.nan
            pos[j, 2] = np.nan
    if not root_ok:
        orient_out[:, :] = np.nan
        return
    for t in range(order.shape[0]):
        j = order[t]
        ok = math.isfinite(rot[j, 0]) and math.isfinite(rot[j, 1]) and math.isfinite(rot[j, 2]) \
            and math.isfinite(rot[j, 3])
        if ok:
            bw, bx, by, bz = rot[j, 0], rot[j, 1], rot[j, 2], rot[j, 3]
        else:
            bw, bx, by, bz = 1.0, 0.0, 0.0, 0.0
        aw, ax, ay, az = rest[j, 0], rest[j, 1], rest[j, 2], rest[j, 3]
        jw, jx, jy, jz = qmul(aw, ax, ay, az, bw, bx, by, bz)
        p = parents[j]
        if p < 0:
            if ok:
                orient_out[j, 0], orient_out[j, 1], orient_out[j, 2], orient_out[j, 3] = jw, jx, jy, jz
            else:
                orient_out[j, 0] = np.nan
                orient_out[j, 1] = np.nan
                orient_out[j, 2] = np.nan
                orient_out[j, 3] = np.nan
            continue
        aw, ax, ay, az = orient_out[p, 0], orient_out[p, 1], orient_out[p, 2], orient_out[p, 3]
        if not ok or not math.isfinite(aw):
            # unknown below here; the product through identity is still what the parents give
            orient_out[j, 0] = np.nan
            orient_out[j, 1] = np.nan
            orient_out[j, 2] = np.nan
            orient_out[j, 3] = np.nan
            continue
        orient_out[j, 0] = aw * jw - ax * jx - ay * jy - az * jz
        orient_out[j, 1] = aw * jx + ax * jw + ay * jz - az * jy
        orient_out[j, 2] = aw * jy - ax * jz + ay * jw + az * jx
        orient_out[j, 3] = aw * jz + ax * jy - ay * jx + az * jw


@kernel
def condition_brute(pos_in, rot_in, root_in, quality, use_quality, skel, dba, pos, rot, orient_out,
                    filled) -> int:
    """A whole frame's conditioning with a brute-force database in one call: :func:`clean`, then
    :func:`complete_brute` when a joint is missing, then :func:`orient`. Returns -2 to hold the last
    target (nothing usable), else the match index (-1: none)."""
    state = clean(pos_in, rot_in, quality, use_quality, pos, rot)
    if state < 0:
        return -2
    match = -1
    if state > 0:
        match = complete_brute(pos, rot, dba, filled)
    else:
        filled[:] = False
    orient(pos, rot, root_in, skel, orient_out)
    return match


def warm() -> None:
    """Compile every kernel here once on small inputs (fills the on-disk cache)."""
    J, k, N = 3, 2, 4
    pos = np.zeros((J, 3))
    pos[1, 1], pos[2, 1] = 0.1, -0.1
    pos[0, 0] = np.nan
    rot = np.tile([1.0, 0, 0, 0], (J, 1))
    pl, pr = np.array([1], dtype=np.int64), np.array([2], dtype=np.int64)
    filled = np.zeros(J, dtype=np.bool_)
    dba = tuple(DBArrays(pl, pr, 0, np.zeros(3 * J), np.ones((k, 3 * J)), np.zeros((k, N)), np.zeros(N), np.zeros(N),
                         np.zeros((N, J, 3)), np.tile([1.0, 0, 0, 0], (N, J, 1)), np.zeros(k), np.zeros(4),
                         np.zeros(2, dtype=np.int64)))
    complete_brute(pos, rot, dba, filled)
    skel = tuple(Skeleton(0, np.arange(J, dtype=np.int64), np.array([-1, 0, 0], dtype=np.int64),
                          np.tile([1.0, 0, 0, 0], (J, 1))))
    out = (np.zeros((J, 3)), np.zeros((J, 4)), np.zeros((J, 4)), filled)
    condition_brute(pos, rot, np.zeros(3), np.full(J, 2, dtype=np.int8), True, skel, dba, *out)
    # the entry points called directly too (the k-d tree path, the search timing)
    nearest(dba[10], dba[5], dba[6], dba[7])
    if query(pos, dba):
        best_full(pos, dba, nearest_m(dba[10], dba[5], dba[6], dba[7], dba[12]))
        fill(0, dba, pos, rot, filled)
    p2, r2 = np.zeros((J, 3)), np.zeros((J, 4))
    clean(pos, rot, np.full(J, 2, dtype=np.int8), True, p2, r2)
    clean(pos, rot, np.zeros(J, dtype=np.int8), False, p2, r2)
    # a node's targets are arrays decoded from CharacterPose: read-only, a signature of their own
    ro_pos, ro_rot, ro_q = readonly(pos), readonly(rot), readonly(np.full(J, 2, dtype=np.int8))
    clean(ro_pos, ro_rot, ro_q, True, p2, r2)
    condition_brute(ro_pos, ro_rot, readonly(np.zeros(3)), ro_q, True, skel, dba, *out)
    orient(p2, rot, np.zeros(3), skel, np.zeros((J, 4)))
