"""Character hierarchy: forward kinematics against a joint-by-joint reference, and refused definitions."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.retarget.character import Character, CharacterError, standard_20


def reference_fk(ch: Character, local: np.ndarray, root: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One joint at a time with scipy Rotation objects: the textbook recursion."""
    world_r: list[Rotation] = []
    world_p = np.zeros((ch.n_joints, 3))
    for j in range(ch.n_joints):
        r = Rotation.from_quat(ch.rest_rotations[j], scalar_first=True) * Rotation.from_quat(local[j], scalar_first=True)
        p = ch.parents[j]
        if p < 0:
            world_r.append(r)
            world_p[j] = root
        else:
            world_r.append(world_r[p] * r)
            world_p[j] = world_p[p] + world_r[p].apply(ch.rest_offsets[j])
    return world_p, np.array([r.as_quat(scalar_first=True) for r in world_r])


def test_rest_pose_of_standard_20_stands_on_the_floor():
    ch = standard_20(1.80)
    pos, rot = ch.rest_pose()
    assert ch.n_joints == 20 and np.isnan(ch.bone_lengths[ch.root])
    assert pos[:, 2].min() == pytest.approx(0.009 * 1.80)            # feet just above the floor
    assert pos[ch.index("Head"), 2] == pytest.approx(0.930 * 1.80)
    # Winter's heights kept under the Kinect-shaped girdles: hip joints 0.530 H, shoulders 0.818 H
    assert pos[[ch.index("HipLeft"), ch.index("HipRight")], 2] == pytest.approx([0.530 * 1.80] * 2)
    assert pos[[ch.index("ShoulderLeft"), ch.index("ShoulderRight")], 2] == pytest.approx([0.818 * 1.80] * 2)
    assert pos[ch.index("KneeLeft"), 2] == pytest.approx(0.285 * 1.80)
    assert np.allclose(np.abs(rot[:, 0]), 1.0)                         # identity everywhere at rest
    left, right = pos[ch.index("HandLeft")], pos[ch.index("HandRight")]
    assert left[1] > 0 > right[1] and left[1] == pytest.approx(-right[1])  # Y is left


def test_forward_kinematics_matches_the_joint_by_joint_recursion():
    rng = np.random.default_rng(3)
    base = standard_20(1.7)
    rest = Rotation.random(base.n_joints, random_state=4).as_quat(scalar_first=True)
    ch = Character("twisted", base.joint_names, base.parents, base.rest_offsets, rest)
    local = Rotation.random((5 * ch.n_joints), random_state=5).as_quat(scalar_first=True).reshape(5, ch.n_joints, 4)
    roots = rng.normal(size=(5, 3))
    pos, rot = ch.forward_kinematics(local, roots)
    for f in range(5):
        ref_p, ref_q = reference_fk(ch, local[f], roots[f])
        assert np.abs(pos[f] - ref_p).max() < 1e-12
        assert np.abs(np.abs(np.einsum("jq,jq->j", rot[f], ref_q)) - 1).max() < 1e-12
    one_p, _ = ch.forward_kinematics(local[2], roots[2])
    assert np.abs(one_p - pos[2]).max() < 1e-15
    # bone lengths never change, whatever the rotations
    d = np.linalg.norm(pos[:, 1:] - pos[:, ch.parents[1:]], axis=2)
    assert np.abs(d - ch.bone_lengths[1:]).max() < 1e-12


@pytest.mark.parametrize("parents, offsets, message", [
    ([-1, 2, 1], [[0, 0, 1], [0, 0, 1], [0, 0, 1]], "does not come before it"),
    ([-1, 5, 1], [[0, 0, 1], [0, 0, 1], [0, 0, 1]], "parent index 5 is not a joint"),
    ([-1, 0, 1], [[0, 0, 1], [0, 0, 0], [0, 0, 1]], "zero-length bone"),
    ([-1, -1, 1], [[0, 0, 1], [0, 0, 1], [0, 0, 1]], "exactly one root"),
])
def test_bad_hierarchies_are_refused_naming_the_joint(parents, offsets, message):
    with pytest.raises(CharacterError, match=message):
        Character("bad", ("a", "b", "c"), parents, offsets, np.tile([1.0, 0, 0, 0], (3, 1)))


def test_non_unit_rest_rotation_and_implausible_height_are_refused():
    with pytest.raises(CharacterError, match="'b': rest rotation is not a unit quaternion"):
        Character("bad", ("a", "b"), [-1, 0], [[0, 0, 1], [0, 0, 1]], [[1, 0, 0, 0], [2, 0, 0, 0]])
    with pytest.raises(CharacterError, match="height"):
        standard_20(17.0)
