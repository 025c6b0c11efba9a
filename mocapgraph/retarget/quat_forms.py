"""Quaternion algebra as constant linear and quadratic forms, and one-leg IK in plain floats.

The building blocks of the retargeter's one-frame numpy path (:mod:`live`): a quaternion product
with a constant is a 4x4 map (``left_map``, ``right_map``), a rotation of a constant vector a
16 x 3 quadratic form (``ROT``), so a frame's arithmetic folds into a few matrix products; and the
same operations on plain floats where a frame has only one or two of them (a numpy call costs
microseconds whatever its size). Quaternions wxyz, unit where a rotation is meant; vectors in m.
"""
from __future__ import annotations

import math

import numpy as np

from ..kinematics.quaternion import HAMILTON as HAM
from ..kinematics.quaternion import matrix_to_quat

# HAM: the Hamilton product as a bilinear form, (a ⊗ b).reshape(16) @ HAM = a * b (kinematics.quaternion)
CONJ16 = np.repeat([1.0, -1.0, -1.0, -1.0], 4)[:, None]                                   # a -> conj(a)
ID = np.array([1.0, 0.0, 0.0, 0.0])
PHASE = np.array([0.0, -0.5 * np.pi])     # cos(h - pi/2) = sin(h)
ONES4 = np.ones(4)
ONES3 = np.ones(3)
N2_LO, N2_HI = (1.0 - 1e-3) ** 2, (1.0 + 1e-3) ** 2   # |q| within 1e-3 of 1, squared
# rotation matrix of a unit q as a quadratic form: R(q)[r, c] = sum_ab q_a q_b ROT[4a+b, r, c]
ROT = np.zeros((16, 3, 3))
for (_r, _c), _ts in {
        (0, 0): [(0, 0, 1), (1, 1, 1), (2, 2, -1), (3, 3, -1)], (1, 1): [(0, 0, 1), (1, 1, -1), (2, 2, 1), (3, 3, -1)],
        (2, 2): [(0, 0, 1), (1, 1, -1), (2, 2, -1), (3, 3, 1)],
        (0, 1): [(1, 2, 2), (0, 3, -2)], (1, 0): [(1, 2, 2), (0, 3, 2)], (0, 2): [(1, 3, 2), (0, 2, 2)],
        (2, 0): [(1, 3, 2), (0, 2, -2)], (1, 2): [(2, 3, 2), (0, 1, -2)], (2, 1): [(2, 3, 2), (0, 1, 2)]}.items():
    for _a, _b, _k in _ts:
        ROT[4 * _a + _b, _r, _c] += _k
# a · b and a x b from the outer product a ⊗ b [9]: [dot, cross]
DOTCROSS = np.zeros((9, 4))
DOTCROSS[[0, 4, 8], 0] = 1.0
for _i, (_j, _k) in enumerate(((1, 2), (2, 0), (0, 1))):
    DOTCROSS[3 * _j + _k, 1 + _i] += 1.0
    DOTCROSS[3 * _k + _j, 1 + _i] -= 1.0


def left_map(p: np.ndarray) -> np.ndarray:
    """4x4 matrix of q -> p * q."""
    return np.einsum("kli,k->il", HAM.reshape(4, 4, 4), p)


def right_map(p: np.ndarray) -> np.ndarray:
    """4x4 matrix of q -> q * p."""
    return np.einsum("kli,l->ik", HAM.reshape(4, 4, 4), p)


def rotate_const(q: np.ndarray, forms: np.ndarray) -> np.ndarray:
    """R(q[i]) v[i] for unit q [n, 4], with forms [n, 16, 3] = ROT @ v[i] precomputed."""
    return ((q[:, :, None] * q[:, None, :]).reshape(-1, 1, 16) @ forms)[:, 0]


def between_rows(a: np.ndarray, b: np.ndarray, a_len: np.ndarray | None = None,
             b_len2: np.ndarray | None = None) -> np.ndarray:
    """Shortest-arc unit quaternions [n, 4] turning directions a onto b [n, 3] (a_len: |a|, b_len2:
    |b|², when known). Antiparallel pairs go through matrix_between's own choice, as the batched path."""
    dc = (a[:, :, None] * b[:, None, :]).reshape(-1, 9) @ DOTCROSS                       # [a.b, a x b]
    bb = np.einsum("ij,ij->i", b, b) if b_len2 is None else b_len2
    ab = np.sqrt(bb * (a_len * a_len if a_len is not None else np.einsum("ij,ij->i", a, a)))
    dc[:, 0] += ab
    if not float((dc[:, 0] / ab).min()) >= 1e-9:    # antiparallel (or zero-length: NaN) somewhere
        from ..kinematics.quaternion import matrix_between
        return matrix_to_quat(matrix_between(a, b))
    return dc / np.sqrt(np.einsum("ij,ij->i", dc, dc))[:, None]


def power_left(qs: list, rel: list, f2: np.ndarray, phase: np.ndarray) -> np.ndarray:
    """qs · rel^f for two unit quaternions (plain floats, wxyz) and fractions f [k] (shortest arc
    first): [k, 4]. ``f2`` [k, 2] is f twice and ``phase`` [2] is (0, -pi/2), so that one cos gives
    the cos and sin of every half angle and one product the quaternions."""
    w, x, y, z = rel if rel[0] >= 0 else [-v for v in rel]
    s = math.sqrt(x * x + y * y + z * z)
    ax = [x / s, y / s, z / s] if s > 1e-15 else [0.0, 0.0, 0.0]
    a, b, c, d = qs
    # qs * (cos h, sin h · axis) = cos h · qs + sin h · (qs * (0, axis))
    u = [-b * ax[0] - c * ax[1] - d * ax[2], a * ax[0] + c * ax[2] - d * ax[1],
         a * ax[1] - b * ax[2] + d * ax[0], a * ax[2] + b * ax[1] - c * ax[0]]
    return np.cos(f2 * math.atan2(s, w) + phase) @ np.array([qs, u])


def v_between(a: list, b: list) -> list:
    """Shortest-arc unit quaternion (floats) turning direction a onto b (3 floats each); the
    antiparallel case through the batched helpers' own choice."""
    dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    ab = math.sqrt((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]) * (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]))
    w = ab + dot
    if w < 1e-9 * ab:
        return between_rows(np.array([a]), np.array([b]))[0].tolist()
    q = [w, a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return [x / n for x in q]


def v_rotate(q: list, v: list) -> list:
    """v rotated by the unit quaternion q (floats)."""
    w, x, y, z = q
    tx, ty, tz = 2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])
    return [v[0] + w * tx + y * tz - z * ty, v[1] + w * ty + z * tx - x * tz, v[2] + w * tz + x * ty - y * tx]


def leg_ik(hip: list, knee: list, ankle: list, target: list, l1: float, l2: float, pole: list):
    """foot_planting.two_bone_ik for one leg in plain floats: (thigh turn, shin turn) as unit
    quaternions, the knee kept in the leg's bend plane (``pole`` where the leg is straight)."""
    to = [target[i] - hip[i] for i in range(3)]
    dist = math.sqrt(to[0] ** 2 + to[1] ** 2 + to[2] ** 2)
    u = [x / max(dist, 1e-12) for x in to]
    d = min(max(dist, abs(l1 - l2) + 1e-6), l1 + l2 - 1e-6)
    cos_a = min(max((l1 * l1 + d * d - l2 * l2) / (2 * l1 * d), -1.0), 1.0)
    sin_a = math.sqrt(1.0 - cos_a * cos_a)
    k = [knee[i] - hip[i] for i in range(3)]
    ku = k[0] * u[0] + k[1] * u[1] + k[2] * u[2]
    perp = [k[i] - ku * u[i] for i in range(3)]
    if math.sqrt(perp[0] ** 2 + perp[1] ** 2 + perp[2] ** 2) > 1e-6 * l1:
        v = perp
    else:
        pu = pole[0] * u[0] + pole[1] * u[1] + pole[2] * u[2]
        v = [pole[i] - pu * u[i] for i in range(3)]
    vn = max(math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2), 1e-12)
    knee_new = [hip[i] + l1 * (cos_a * u[i] + sin_a * v[i] / vn) for i in range(3)]
    reach = [hip[i] + d * u[i] for i in range(3)]
    q1 = v_between(k, [knee_new[i] - hip[i] for i in range(3)])
    shin = v_rotate(q1, [ankle[i] - knee[i] for i in range(3)])   # ankle_after - knee_new
    q2 = v_between(shin, [reach[i] - knee_new[i] for i in range(3)])
    return q1, q2
