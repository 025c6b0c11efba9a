"""Compiled rotation building blocks that other kernel modules call: the quaternion product, a rotation matrix's quaternion, a symmetric matrix's eigenvectors.

Shared by source_kernels (rotations from points), rigid_kernels (limb fits), the retargeting
kernels and the physics kernels (:func:`qmul` is the one compiled Hamilton product; its numpy
twin is :func:`mocapgraph.kinematics.quaternion.quat_multiply`, tested against it); a module calling these declares it (``kernel = kernel_calling(quat_kernels)``,
see mocapgraph.jit) so that its cache follows changes here. Quaternions wxyz, w >= 0.
"""
from __future__ import annotations

import numpy as np

from ..jit import kernel


@kernel
def qmul(aw, ax, ay, az, bw, bx, by, bz):
    """The Hamilton product a * b of two wxyz quaternions given as floats: (w, x, y, z)."""
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


@kernel
def matrix_to_quat_into(m00, m01, m02, m10, m11, m12, m20, m21, m22, out, j):
    """out[j] = the wxyz quaternion (w >= 0) of the rotation matrix m, exactly as
    quaternion.matrix_to_quat (Shepperd: the row of 4 q q^T with the largest diagonal, normalised)."""
    d0 = 1.0 + m00 + m11 + m22
    d1 = 1.0 + m00 - m11 - m22
    d2 = 1.0 - m00 + m11 - m22
    d3 = 1.0 - m00 - m11 + m22
    # np.argmax: the first of equal maxima
    k, best = 0, d0
    if d1 > best:
        k, best = 1, d1
    if d2 > best:
        k, best = 2, d2
    if d3 > best:
        k = 3
    if k == 0:
        q0, q1, q2, q3 = d0, m21 - m12, m02 - m20, m10 - m01
    elif k == 1:
        q0, q1, q2, q3 = m21 - m12, d1, m10 + m01, m02 + m20
    elif k == 2:
        q0, q1, q2, q3 = m02 - m20, m10 + m01, d2, m21 + m12
    else:
        q0, q1, q2, q3 = m10 - m01, m02 + m20, m21 + m12, d3
    s = 1.0 / np.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    if q0 < 0.0:
        s = -s
    out[j, 0], out[j, 1], out[j, 2], out[j, 3] = q0 * s, q1 * s, q2 * s, q3 * s


@kernel
def jacobi_eigen(A: np.ndarray, V: np.ndarray, vectors: bool) -> None:
    """Diagonalise the symmetric n x n A in place by cyclic Jacobi rotations (eigenvalues on its
    diagonal, A <- V^T A V); with ``vectors``, V (set to I here) gets the eigenvectors as columns."""
    n = A.shape[0]
    if vectors:
        for i in range(n):
            for j in range(n):
                V[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(50):
        off = 0.0
        scale = 0.0
        for i in range(n):
            scale += A[i, i] * A[i, i]
            for j in range(i + 1, n):
                off += A[i, j] * A[i, j]
        # Off-diagonal norm below 1e-15 of the diagonal's: eigenvalues and vectors exact to rounding.
        if off <= 1e-30 * scale:
            return
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = A[p, q]
                if apq == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * apq)
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                cs = 1.0 / np.sqrt(t * t + 1.0)
                sn = t * cs
                for k in range(n):          # A <- A J
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = cs * akp - sn * akq
                    A[k, q] = sn * akp + cs * akq
                for k in range(n):          # A <- J^T A
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = cs * apk - sn * aqk
                    A[q, k] = sn * apk + cs * aqk
                if vectors:
                    for k in range(n):      # V <- V J
                        vkp, vkq = V[k, p], V[k, q]
                        V[k, p] = cs * vkp - sn * vkq
                        V[k, q] = sn * vkp + cs * vkq


def warm() -> None:
    """Compile them on two quaternions, a small rotation and a 4x4 and a 3x3 symmetric matrix."""
    qmul(1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0)
    out = np.zeros((1, 4))
    matrix_to_quat_into(1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0, out, 0)
    for n in (3, 4):
        A = np.eye(n) + 0.1
        jacobi_eigen(A, np.zeros((n, n)), True)
        jacobi_eigen(np.eye(n) + 0.1, np.zeros((n, n)), False)
