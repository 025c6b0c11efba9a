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


def quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotations [..., 4] taking directions a onto b ([..., 3], any length).

    Antiparallel pairs turn by pi about an axis perpendicular to a (any such axis is shortest).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    w = 1.0 + np.sum(a * b, axis=-1)
    xyz = np.cross(a, b)
    flip = w < 1e-9
    if np.any(flip):
        # a perpendicular axis: a x X, or a x Y when a is along X
        alt = np.cross(a, np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
        xyz = np.where(flip[..., None], alt, xyz)
        w = np.where(flip, 0.0, w)
    q = np.concatenate([w[..., None], xyz], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v [..., 3] rotated by unit quaternions q [..., 4] (broadcasting)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + q[..., :1] * t + np.cross(u, t)


def quat_power(q: np.ndarray, f) -> np.ndarray:
    """q^f: the rotation about q's axis by f times its angle (f broadcasts; shortest arc first)."""
    q = np.asarray(q, dtype=np.float64)
    q = q * np.where(q[..., :1] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    half = np.arctan2(s, q[..., 0]) * f
    with np.errstate(invalid="ignore", divide="ignore"):
        axis = np.where(s[..., None] > 1e-15, q[..., 1:] / s[..., None], 0.0)
    return np.concatenate([np.cos(half)[..., None], np.sin(half)[..., None] * axis], axis=-1)


def swing_twist(q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Decompose q = swing * twist with twist about ``axis`` (unit, q's own frame) [..., 4] each."""
    q = np.asarray(q, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=-1, keepdims=True)
    proj = np.sum(q[..., 1:] * axis, axis=-1, keepdims=True) * axis
    twist = np.concatenate([q[..., :1], np.broadcast_to(proj, q.shape[:-1] + (3,))], axis=-1)
    n = np.linalg.norm(twist, axis=-1, keepdims=True)
    twist = np.where(n > 1e-12, twist / np.where(n > 1e-12, n, 1.0), [1.0, 0.0, 0.0, 0.0])
    swing = quat_multiply(q, quat_conjugate(twist))
    return swing, twist


def twist_angle(twist: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Signed angle (rad, in (-pi, pi]) of a twist quaternion about ``axis``."""
    s = np.sum(np.asarray(twist)[..., 1:] * axis, axis=-1)
    ang = 2.0 * np.arctan2(s, twist[..., 0])
    return (ang + np.pi) % (2 * np.pi) - np.pi
