"""Shum & Ho Eq 3-4: bone lengths become the character's, directions stay the source's, NaN handled."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.kinematics.bone_length_retarget import retarget_bone_lengths
from mocapgraph.kinematics.character import standard_20


def _noisy_source(frames: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """A 1.62 m performer in random poses (noisy joints, so bone lengths vary per frame)."""
    rng = np.random.default_rng(seed)
    src = standard_20(1.62)
    local = rng.normal(size=(frames, src.n_joints, 4))
    local[..., 0] += 3.0                     # moderate rotations
    local /= np.linalg.norm(local, axis=-1, keepdims=True)
    pos, _ = src.forward_kinematics(local, rng.normal(size=(frames, 3)))
    return pos + rng.normal(scale=0.01, size=pos.shape), src.parents


def test_lengths_exact_directions_kept_root_kept():
    pos, parents = _noisy_source(50)
    target = standard_20(1.93)
    out = retarget_bone_lengths(pos, parents, target.bone_lengths)
    child = np.flatnonzero(parents >= 0)
    bones = out[:, child] - out[:, parents[child]]
    assert np.abs(np.linalg.norm(bones, axis=-1) - target.bone_lengths[child]).max() < 1e-12
    src_bones = pos[:, child] - pos[:, parents[child]]
    cos = np.sum(bones * src_bones, -1) / np.linalg.norm(bones, axis=-1) / np.linalg.norm(src_bones, axis=-1)
    assert np.arccos(np.clip(cos, -1, 1)).max() < 1e-7
    assert np.array_equal(out[:, 0], pos[:, 0])


def test_matches_the_papers_recursion_joint_by_joint():
    pos, parents = _noisy_source(3, seed=7)
    lengths = standard_20(1.5).bone_lengths
    ref = np.empty_like(pos)
    for f in range(len(pos)):
        for i in range(len(parents)):   # parents precede children: the paper's top-down order
            j = parents[i]
            if j < 0:
                ref[f, i] = pos[f, i]
            else:
                d = (pos[f, i] - pos[f, j]) / np.linalg.norm(pos[f, i] - pos[f, j])
                ref[f, i] = ref[f, j] + d * lengths[i]
    assert np.abs(retarget_bone_lengths(pos, parents, lengths) - ref).max() < 1e-12
    # one frame without the F axis gives the same
    assert np.abs(retarget_bone_lengths(pos[1], parents, lengths) - ref[1]).max() < 1e-12


def test_missing_joint_is_nan_below_it_or_filled_from_the_rest_pose_and_marked():
    ch = standard_20(1.7)
    pos, parents = _noisy_source(4, seed=2)
    elbow, wrist, hand = ch.index("ElbowLeft"), ch.index("WristLeft"), ch.index("HandLeft")
    pos[1, elbow] = np.nan
    out = retarget_bone_lengths(pos, parents, ch.bone_lengths)
    assert np.isnan(out[1, [elbow, wrist, hand]]).all()
    assert np.isfinite(np.delete(out[1], [elbow, wrist, hand], axis=0)).all()
    assert np.isfinite(out[[0, 2, 3]]).all()

    rest, _ = ch.rest_pose()
    rest_dirs = rest - rest[np.maximum(parents, 0)]
    rest_dirs[0] = (0, 0, 1)
    filled, est = retarget_bone_lengths(pos, parents, ch.bone_lengths, fallback_directions=rest_dirs,
                                        return_estimated=True)
    assert np.isfinite(filled).all()
    # elbow and wrist directions both need the elbow: from the rest pose; the hand hangs from them
    assert set(np.flatnonzero(est[1])) == {elbow, wrist, hand}
    assert np.allclose((filled[1, elbow] - filled[1, ch.index("ShoulderLeft")]) / ch.bone_lengths[elbow], (0, 1, 0))
    assert not est[[0, 2, 3]].any()


def test_hand_below_a_filled_joint_is_estimated_too():
    ch = standard_20(1.7)
    pos, parents = _noisy_source(1, seed=5)
    wrist, hand = ch.index("WristLeft"), ch.index("HandLeft")
    pos[0, wrist] = np.nan            # wrist->elbow and hand->wrist directions are both unknown
    _, est = retarget_bone_lengths(pos, parents, ch.bone_lengths, fallback_directions=np.tile((0, 0, 1.0), (20, 1)),
                                   return_estimated=True)
    assert set(np.flatnonzero(est[0])) == {wrist, hand}


def test_zero_length_source_bone_and_bad_hierarchies():
    ch = standard_20(1.7)
    pos, parents = _noisy_source(1, seed=3)
    pos[0, ch.index("HandLeft")] = pos[0, ch.index("WristLeft")]   # coincident: no direction
    out = retarget_bone_lengths(pos, parents, ch.bone_lengths)
    assert np.isnan(out[0, ch.index("HandLeft")]).all() and np.isfinite(out[0, ch.index("WristLeft")]).all()
    with pytest.raises(ValueError, match="cycle"):
        retarget_bone_lengths(np.zeros((3, 3)), [-1, 2, 1], np.ones(3))
    with pytest.raises(ValueError, match="not a joint"):
        retarget_bone_lengths(np.zeros((3, 3)), [-1, 0, 5], np.ones(3))
    with pytest.raises(ValueError, match="bone lengths"):
        retarget_bone_lengths(np.zeros((3, 3)), [-1, 0, 1], np.ones(2))
