"""The compiled rotation building blocks against their numpy twins: the Hamilton product (qmul against
quat_multiply and scipy's Rotation) and a rotation matrix's quaternion (against matrix_to_quat)."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.quat_kernels import matrix_to_quat_into, qmul
from mocapgraph.kinematics.quaternion import matrix_to_quat, quat_multiply


def test_qmul_is_the_hamilton_product_of_numpy_and_scipy() -> None:
    rng = np.random.default_rng(20261206)
    a, b = rng.normal(size=(2, 200, 4))
    got = np.array([qmul(*x, *y) for x, y in zip(a, b)])
    np.testing.assert_allclose(got, quat_multiply(a, b), atol=1e-15)
    ua, ub = a / np.linalg.norm(a, axis=1, keepdims=True), b / np.linalg.norm(b, axis=1, keepdims=True)
    unit = np.array([qmul(*x, *y) for x, y in zip(ua, ub)])
    ref = (Rotation.from_quat(ua, scalar_first=True) * Rotation.from_quat(ub, scalar_first=True)).as_quat(scalar_first=True)
    np.testing.assert_allclose(unit * np.sign(unit[:, :1]), ref * np.sign(ref[:, :1]), atol=1e-12)


def test_matrix_to_quat_into_matches_numpy() -> None:
    m = Rotation.random(100, random_state=7).as_matrix()
    out = np.zeros((100, 4))
    for j in range(100):
        matrix_to_quat_into(*m[j].reshape(9), out, j)
    np.testing.assert_allclose(out, matrix_to_quat(m), atol=1e-12)
