"""Quaternion helpers (products, matrices, conjugates) agree with scipy's Rotation (the reference) to rounding."""
import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.quaternion import matrix_to_quat, quat_conjugate, quat_multiply, quat_to_matrix


def test_helpers_agree_with_scipy():
    a = Rotation.random(500, random_state=1)
    b = Rotation.random(500, random_state=2)
    # include the awkward cases: identity, half turns about each axis (w = 0)
    extra = Rotation.from_rotvec(np.array([[0, 0, 0], [np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi], [1e-9, 0, 0]]))
    a = Rotation.concatenate([a, extra])
    qa, qb = a.as_quat(scalar_first=True), Rotation.concatenate([b, extra]).as_quat(scalar_first=True)
    assert np.abs(quat_to_matrix(qa) - a.as_matrix()).max() < 1e-14
    q = matrix_to_quat(a.as_matrix().reshape(5, 101, 3, 3)).reshape(-1, 4)
    assert (q[:, 0] >= 0).all()
    assert np.abs(np.abs(np.einsum("ij,ij->i", q, qa)) - 1).max() < 1e-13
    ref = (Rotation.from_quat(qa, scalar_first=True) * Rotation.from_quat(qb, scalar_first=True)).as_quat(scalar_first=True)
    assert np.abs(np.abs(np.einsum("ij,ij->i", quat_multiply(qa, qb), ref)) - 1).max() < 1e-13
    ident = quat_multiply(qa, quat_conjugate(qa))
    assert np.abs(ident - [1, 0, 0, 0]).max() < 1e-13


def test_the_row_wise_products_are_the_hamilton_product():
    """quat_multiply_rows and quat_multiply_conj_rows (the per-frame form the physics and the live
    retargeter use) give scipy's composition, and quat_multiply's values to rounding."""
    from mocapgraph.kinematics.quaternion import quat_multiply_conj_rows, quat_multiply_rows
    a = Rotation.random(300, random_state=3).as_quat(scalar_first=True)
    b = Rotation.random(300, random_state=4).as_quat(scalar_first=True)
    ref = (Rotation.from_quat(a, scalar_first=True) * Rotation.from_quat(b, scalar_first=True)).as_quat(scalar_first=True)
    rows = quat_multiply_rows(a, b)
    assert np.abs(np.abs(np.einsum("ij,ij->i", rows, ref)) - 1).max() < 1e-13
    assert np.abs(rows - quat_multiply(a, b)).max() < 1e-15
    assert np.abs(quat_multiply_conj_rows(a, b) - quat_multiply(a, quat_conjugate(b))).max() < 1e-15
