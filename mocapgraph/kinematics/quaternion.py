"""Batched wxyz quaternion and rotation-matrix arithmetic for per-frame hot paths.

scipy.spatial.transform.Rotation is the reference (and what the tests compare against), but each
of its calls costs 0.1-0.5 ms for a handful of rotations (object construction, validation), which is
the whole budget of a live frame. These functions are plain numpy on arrays of any leading shape,
wxyz order, matrices acting on column vectors; they agree with scipy to rounding.
"""
from __future__ import annotations

import numpy as np


# m = I + 2 * (linear map of the 16 products q_a q_b) for a unit q: one outer product and one
# matrix product instead of two dozen element-wise operations (this sits on every live frame)
_Q2M = np.zeros((16, 9))
_TERMS = {  # element (row-major index) -> [(a, b, coefficient)] over q = (w, x, y, z)
    0: [(2, 2, -1), (3, 3, -1)], 1: [(1, 2, 1), (0, 3, -1)], 2: [(1, 3, 1), (0, 2, 1)],
    3: [(1, 2, 1), (0, 3, 1)], 4: [(1, 1, -1), (3, 3, -1)], 5: [(2, 3, 1), (0, 1, -1)],
    6: [(1, 3, 1), (0, 2, -1)], 7: [(2, 3, 1), (0, 1, 1)], 8: [(1, 1, -1), (2, 2, -1)],
}
for _e, _terms in _TERMS.items():
    for _a, _b, _c in _terms:
        _Q2M[4 * _a + _b, _e] += 2.0 * _c
_EYE9 = np.eye(3).reshape(9)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] of quaternions [..., 4] (wxyz; normalised here)."""
    q = np.asarray(q, dtype=np.float64)
    n2 = np.sum(q * q, axis=-1, keepdims=True)
    outer = (q[..., :, None] * q[..., None, :]).reshape(q.shape[:-1] + (16,)) / n2
    return (outer @ _Q2M + _EYE9).reshape(q.shape[:-1] + (3, 3))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (broadcasting); np.cross costs several times more on tiny arrays."""
    a1, a2, a3 = a[..., 0], a[..., 1], a[..., 2]
    b1, b2, b3 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1], axis=-1)


def norm(v: np.ndarray, keepdims: bool = False) -> np.ndarray:
    """Euclidean length over the last axis (np.linalg.norm without its overhead)."""
    return np.sqrt(np.sum(v * v, axis=-1, keepdims=keepdims))


_EPS = np.zeros((3, 3, 3))
_EPS[0, 1, 2] = _EPS[1, 2, 0] = _EPS[2, 0, 1] = 1.0
_EPS[0, 2, 1] = _EPS[2, 1, 0] = _EPS[1, 0, 2] = -1.0
_SKEW = np.zeros((3, 9))   # v -> [v]x, row-major
_SKEW[0, 5], _SKEW[0, 7], _SKEW[1, 2], _SKEW[1, 6], _SKEW[2, 1], _SKEW[2, 3] = -1, 1, 1, -1, -1, 1


def matrix_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation matrices [..., 3, 3] taking directions a onto b: for unit vectors,
    R = c I + [v]x + v v^T / (1 + c) with v = a x b, c = a . b (the antiparallel case through
    :func:`quat_between`)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / norm(a, True)
    b = b / norm(b, True)
    v = np.einsum("ijk,...j,...k->...i", _EPS, a, b)
    c = np.einsum("...i,...i->...", a, b)
    if np.any(c < -1.0 + 1e-9):
        return quat_to_matrix(quat_between(a, b))
    outer = v[..., :, None] * (v / (1.0 + c)[..., None])[..., None, :]
    return outer + (v @ _SKEW).reshape(v.shape[:-1] + (3, 3)) + c[..., None, None] * np.eye(3)


# Shepperd: row k of the symmetric matrix C = 4 q q^T is 4 q_k q; with k the largest of the four
# squared components (the diagonal of C) that row is the quaternion times a scale far from zero,
# so normalising it loses no precision. Every entry of C is linear in the matrix entries.
_C = np.zeros((9, 16))
_C0 = np.zeros(16)
for _k, _d in enumerate(([1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1])):   # diag: 1 + sum(+-m_ii)
    _C0[5 * _k] = 1.0
    _C[[0, 4, 8], 5 * _k] = _d
for (_a, _b), (_i, _j, _s) in {(0, 1): (7, 5, -1), (0, 2): (2, 6, -1), (0, 3): (3, 1, -1),
                                 (1, 2): (3, 1, 1), (1, 3): (2, 6, 1), (2, 3): (7, 5, 1)}.items():
    for _e in (4 * _a + _b, 4 * _b + _a):   # C[a, b] = m_i + s m_j
        _C[_i, _e], _C[_j, _e] = 1.0, float(_s)
_EYE4 = np.eye(4)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """wxyz quaternions [..., 4] with w >= 0 of rotation matrices [..., 3, 3] (Shepperd's method:
    each quaternion from the largest of its four squared components, so no precision is lost)."""
    m = np.asarray(m, dtype=np.float64)
    lead = m.shape[:-2]
    c = (m.reshape(-1, 9) @ _C + _C0).reshape(-1, 4, 4)                 # 4 q q^T
    k = np.argmax(c.reshape(-1, 16)[:, ::5], axis=1)
    q = np.einsum("nk,nkj->nj", _EYE4[k], c)
    q *= (np.where(q[:, :1] < 0, -1.0, 1.0) / np.sqrt(np.einsum("nj,nj->n", q, q))[:, None])
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


# The Hamilton product as a bilinear form: (a ⊗ b).reshape(16) @ HAMILTON = a * b (row 4i + j: e_i * e_j);
# with the 16 pairwise products of each row, a row-wise product is two numpy operations instead of
# ~30 column operations (the same terms summed: the same result as quat_multiply to one rounding).
_E4 = np.eye(4)
HAMILTON = np.stack([quat_multiply(_E4[i], _E4[j]) for i in range(4) for j in range(4)])     # [16, 4]
HAMILTON_CONJ = HAMILTON * np.tile([1.0, -1.0, -1.0, -1.0], 4)[:, None]                      # a * conj(b)


def quat_multiply_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamilton products a * b of [N, 4] wxyz arrays (the per-frame form of quat_multiply)."""
    return (a[:, :, None] * b[:, None, :]).reshape(-1, 16) @ HAMILTON


def quat_multiply_conj_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a * conj(b) of [N, 4] wxyz arrays."""
    return (a[:, :, None] * b[:, None, :]).reshape(-1, 16) @ HAMILTON_CONJ


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
    a = a / norm(a, True)
    b = b / norm(b, True)
    w = 1.0 + np.sum(a * b, axis=-1)
    xyz = cross(a, b)
    flip = w < 1e-9
    if np.any(flip):
        # a perpendicular axis: a x X, or a x Y when a is along X
        alt = cross(a, np.where(np.abs(a[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
        xyz = np.where(flip[..., None], alt, xyz)
        w = np.where(flip, 0.0, w)
    q = np.concatenate([w[..., None], xyz], axis=-1)
    return q / norm(q, True)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors v [..., 3] rotated by unit quaternions q [..., 4] (broadcasting)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    u = q[..., 1:]
    t = 2.0 * cross(u, v)
    return v + q[..., :1] * t + cross(u, t)


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
