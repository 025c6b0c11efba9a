"""Fast quaternion helpers agree with scipy's Rotation (the reference) to rounding."""
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
