"""Batched wxyz quaternion and rotation-matrix arithmetic for per-frame hot paths.

scipy.spatial.transform.Rotation is the reference (and what the tests compare against), but each
of its calls costs 0.1-0.5 ms for a handful of rotations (object construction, validation), which is
the whole budget of a live frame. These functions are plain numpy on arrays of any leading shape,
wxyz order, matrices acting on column vectors; they agree with scipy to rounding.
"""
from __future__ import annotations

import numpy as np


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of quaternions [..., 4] (wxyz; normalised here)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    m = np.empty(q.shape[:-1] + (3, 3))
    m[..., 0, 0] = 1 - 2 * (yy + zz)
    m[..., 0, 1] = 2 * (xy - wz)
    m[..., 0, 2] = 2 * (xz + wy)
    m[..., 1, 0] = 2 * (xy + wz)
    m[..., 1, 1] = 1 - 2 * (xx + zz)
    m[..., 1, 2] = 2 * (yz - wx)
    m[..., 2, 0] = 2 * (xz - wy)
    m[..., 2, 1] = 2 * (yz + wx)
    m[..., 2, 2] = 1 - 2 * (xx + yy)
    return m


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """wxyz quaternions [..., 4] with w >= 0 of rotation matrices [..., 3, 3] (Shepperd's method:
    each quaternion from the largest of its four squared components, so no precision is lost)."""
    m = np.asarray(m, dtype=np.float64)
    lead = m.shape[:-2]
    flat = m.reshape(-1, 3, 3)
    m00, m11, m22 = flat[:, 0, 0], flat[:, 1, 1], flat[:, 2, 2]
    # 4 * squared components (w, x, y, z); pick the largest per matrix
    sq = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], axis=1)
    k = np.argmax(sq, axis=1)
    s = np.sqrt(np.maximum(sq[np.arange(len(k)), k], 1e-300))  # = 4 * |component k| / 2 ... = 2|q_k|
    d21, d02, d10 = flat[:, 2, 1] - flat[:, 1, 2], flat[:, 0, 2] - flat[:, 2, 0], flat[:, 1, 0] - flat[:, 0, 1]
    a10, a02, a21 = flat[:, 1, 0] + flat[:, 0, 1], flat[:, 0, 2] + flat[:, 2, 0], flat[:, 2, 1] + flat[:, 1, 2]
    # rows: the quaternion times 2s when component k is the largest
    cand = np.stack([
        np.stack([s * s, d21, d02, d10], axis=1),
        np.stack([d21, s * s, a10, a02], axis=1),
        np.stack([d02, a10, s * s, a21], axis=1),
        np.stack([d10, a02, a21, s * s], axis=1),
    ], axis=1)
    q = cand[np.arange(len(k)), k] / (2.0 * s)[:, None]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(lead + (4,))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of wxyz quaternions (broadcasting): rotate by b, then by a."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_conjugate(q: np.ndarray) -> np.ndarray:
    """Inverse of unit wxyz quaternions."""
    out = np.array(q, dtype=np.float64, copy=True)
    out[..., 1:] *= -1.0
    return out
