"""Compiled one-frame :func:`source.rotations_from_points`: a positions-only source's world rotations from its points.

The numpy function stays the reference (and the batch path); this kernel does the same arithmetic
for one frame joint by joint in the plan's topological order (a parent before its children), so
a live Kinect frame costs microseconds instead of the per-level numpy calls' milliseconds. The
girdles' best fit (Kabsch by SVD in numpy) is here Horn's quaternion form of the same problem:
the eigenvector of the largest eigenvalue of a symmetric 4x4 matrix, found by cyclic Jacobi
rotations (accurate to rounding; one 4x4 scratch pair a call); both maximise sum cur_k . R rest_k
over proper rotations, so they agree wherever that maximum is unique (FIT_MIN_GAP makes it NaN in
both where it is not). Points in m (world), rotations wxyz with w >= 0 for the fitted and triad joints.
"""
from __future__ import annotations

import numpy as np

from mocapgraph.jit import kernel_calling

from ..kinematics import quat_kernels

kernel = kernel_calling(quat_kernels)   # matrix_to_quat_into, jacobi_eigen

# joint kinds (PointRotationPlan.kind)
CARRY, ONE, TWO, FIT = 0, 1, 2, 3


@kernel
def _unit3(x, y, z):
    n = np.sqrt(x * x + y * y + z * z)
    return x / n, y / n, z / n


@kernel
def point_rotations(points, index, rest, fit_kids, fit_rest, min_sin, min_gap, out):
    """World rotations out [P, 4] (wxyz) of one frame's points [P, 3] (m, NaN: missing), as
    source.rotations_from_points, from PointRotationPlan's frame_index [P, 7] (column 0
    the order, then per joint parent, kind, primary, secondary a and b, fit row), frame_rest
    [P, 12] (the rest primary direction, the rest frame row-major), fit_kids, fit_rest. ``min_sin``: a triad whose two axes are closer than this sine is NaN;
    ``min_gap``: a best fit whose top two eigenvalues are closer than this times its bone count is
    NaN (the rotation undetermined: collinear bones, or a mirror image symmetric about its axes).
    NaN wherever a needed point is missing."""
    A = np.empty((4, 4))     # the best fit's scratch: one allocation a call, none in the loop
    V = np.empty((4, 4))
    for i in range(index.shape[0]):
        j = index[i, 0]
        pj = index[j, 1]
        if pj >= 0:
            cw, cx, cy, cz = out[pj, 0], out[pj, 1], out[pj, 2], out[pj, 3]
        else:
            cw, cx, cy, cz = 1.0, 0.0, 0.0, 0.0
        kd = index[j, 2]
        if kd == CARRY:
            out[j, 0], out[j, 1], out[j, 2], out[j, 3] = cw, cx, cy, cz
        elif kd == ONE:
            _one_bone(points, rest, j, index[j, 3], cw, cx, cy, cz, out)
        elif kd == TWO:
            _triad(points, index, rest, j, min_sin, out)
        else:
            _best_fit(points, index, fit_kids, fit_rest, j, min_gap, A, V, out)


@kernel
def _one_bone(points, rest, j, k, cw, cx, cy, cz, out):
    """ONE: the parent's rotation (cw, cx, cy, cz), then the shortest arc from the rest bone
    direction it carries onto the current bone j -> k; into out[j]."""
    # the rest direction carried by the parent (quaternion.quat_rotate) ...
    vx, vy, vz = rest[j, 0], rest[j, 1], rest[j, 2]
    tx = 2.0 * (cy * vz - cz * vy)
    ty = 2.0 * (cz * vx - cx * vz)
    tz = 2.0 * (cx * vy - cy * vx)
    fx = vx + cw * tx + (cy * tz - cz * ty)
    fy = vy + cw * ty + (cz * tx - cx * tz)
    fz = vz + cw * tz + (cx * ty - cy * tx)
    # ... turned by the shortest arc onto the current bone (quaternion.quat_between) ...
    ax, ay, az = _unit3(fx, fy, fz)
    bx, by, bz = _unit3(points[k, 0] - points[j, 0], points[k, 1] - points[j, 1], points[k, 2] - points[j, 2])
    w = 1.0 + (ax * bx + ay * by + az * bz)
    x = ay * bz - az * by
    y = az * bx - ax * bz
    z = ax * by - ay * bx
    if w < 1e-9:
        if abs(ax) < 0.9:        # a x X
            x, y, z = 0.0, az, -ay
        else:                    # a x Y
            x, y, z = -az, 0.0, ax
        w = 0.0
    n = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    # ... after the parent's rotation (quaternion.quat_multiply)
    out[j, 0] = w * cw - x * cx - y * cy - z * cz
    out[j, 1] = w * cx + x * cw + y * cz - z * cy
    out[j, 2] = w * cy - x * cz + y * cw + z * cx
    out[j, 3] = w * cz + x * cy - y * cx + z * cw


@kernel
def _triad(points, index, rest, j, min_sin, out):
    """TWO: the frame of the primary bone j -> k and a secondary direction s1 -> s0 (Gram-Schmidt),
    times the rest frame transposed; NaN when the two are closer than ``min_sin`` or a point is missing."""
    k, s0, s1 = index[j, 3], index[j, 4], index[j, 5]
    a0, a1, a2 = _unit3(points[k, 0] - points[j, 0], points[k, 1] - points[j, 1], points[k, 2] - points[j, 2])
    u0 = points[s0, 0] - points[s1, 0]
    u1 = points[s0, 1] - points[s1, 1]
    u2 = points[s0, 2] - points[s1, 2]
    d = u0 * a0 + u1 * a1 + u2 * a2
    b0, b1, b2 = u0 - d * a0, u1 - d * a1, u2 - d * a2
    nb = np.sqrt(b0 * b0 + b1 * b1 + b2 * b2)
    if not nb > min_sin * np.sqrt(u0 * u0 + u1 * u1 + u2 * u2):
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = np.nan, np.nan, np.nan, np.nan
        return
    b0, b1, b2 = b0 / nb, b1 / nb, b2 / nb
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    if not (np.isfinite(a0 + a1 + a2) and np.isfinite(b0 + b1 + b2) and np.isfinite(c0 + c1 + c2)):
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = np.nan, np.nan, np.nan, np.nan
        return
    # current frame (columns a, b, c) times the rest frame transposed
    r = rest[j]
    m00 = a0 * r[3] + b0 * r[4] + c0 * r[5]
    m01 = a0 * r[6] + b0 * r[7] + c0 * r[8]
    m02 = a0 * r[9] + b0 * r[10] + c0 * r[11]
    m10 = a1 * r[3] + b1 * r[4] + c1 * r[5]
    m11 = a1 * r[6] + b1 * r[7] + c1 * r[8]
    m12 = a1 * r[9] + b1 * r[10] + c1 * r[11]
    m20 = a2 * r[3] + b2 * r[4] + c2 * r[5]
    m21 = a2 * r[6] + b2 * r[7] + c2 * r[8]
    m22 = a2 * r[9] + b2 * r[10] + c2 * r[11]
    quat_kernels.matrix_to_quat_into(m00, m01, m02, m10, m11, m12, m20, m21, m22, out, j)


@kernel
def _best_fit(points, index, fit_kids, fit_rest, j, min_gap, A, V, out):
    """FIT: Horn's 4x4 of S_ab = sum_k rest_a cur_b over unit current bones, its top eigenvector
    (Jacobi, scratch A and V [4, 4]); NaN when the top two eigenvalues are closer than ``min_gap``
    times the bone count (undetermined) or a bone is missing."""
    g = index[j, 6]
    sxx = sxy = sxz = syx = syy = syz = szx = szy = szz = 0.0
    bad = False
    nk = 0
    for kk in range(fit_kids.shape[1]):
        k = fit_kids[g, kk]
        if k < 0:
            continue
        nk += 1
        e0 = points[k, 0] - points[j, 0]
        e1 = points[k, 1] - points[j, 1]
        e2 = points[k, 2] - points[j, 2]
        n = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        e0, e1, e2 = e0 / n, e1 / n, e2 / n
        if not (np.isfinite(e0) and np.isfinite(e1) and np.isfinite(e2) and n > 1e-12):
            bad = True
            break
        r0, r1, r2 = fit_rest[g, kk, 0], fit_rest[g, kk, 1], fit_rest[g, kk, 2]
        sxx += r0 * e0
        sxy += r0 * e1
        sxz += r0 * e2
        syx += r1 * e0
        syy += r1 * e1
        syz += r1 * e2
        szx += r2 * e0
        szy += r2 * e1
        szz += r2 * e2
    if bad or nk == 0:
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = np.nan, np.nan, np.nan, np.nan
        return
    A[0, 0], A[0, 1], A[0, 2], A[0, 3] = sxx + syy + szz, syz - szy, szx - sxz, sxy - syx
    A[1, 1], A[1, 2], A[1, 3] = sxx - syy - szz, sxy + syx, szx + sxz
    A[2, 2], A[2, 3] = -sxx + syy - szz, syz + szy
    A[3, 3] = -sxx - syy + szz
    for p in range(4):
        for q in range(p):
            A[p, q] = A[q, p]
    quat_kernels.jacobi_eigen(A, V, True)
    top, second, col = -np.inf, -np.inf, 0
    for p in range(4):
        lam = A[p, p]
        if lam > top:
            top, second, col = lam, top, p
        elif lam > second:
            second = lam
    if not top - second >= min_gap * nk:
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = np.nan, np.nan, np.nan, np.nan
        return
    w, x, y, z = V[0, col], V[1, col], V[2, col], V[3, col]
    n = np.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    out[j, 0], out[j, 1], out[j, 2], out[j, 3] = w / n, x / n, y / n, z / n
