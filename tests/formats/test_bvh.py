"""BVH reader, forward kinematics (against hand-computed chains), writer round trip."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats.bvh_file import (BVH_TO_WORLD, bvh_to_skeleton, read_bvh,
                                         write_bvh)
from mocapgraph.formats.errors import FormatError

CMU = "bvh/cmu/131_01.bvh"
MIXAMO = "bvh/mixamo/test_freebvh.bvh"


def test_cmu_file(shared_data):
    m = read_bvh(shared_data / CMU)
    assert int((~m.is_end_site).sum()) == 31
    assert m.n_frames == 994 and m.rate_hz == 120.0
    assert m.n_channels == 6 + 30 * 3
    assert set(m.rotation_orders()) - {""} == {"ZYX", "ZXY"}  # mixed orders
    assert m.scale == pytest.approx(0.056444, rel=1e-4)
    assert any("CMU units -> m" in c for c in m.conversions)


def test_mixamo_file(shared_data):
    m = read_bvh(shared_data / MIXAMO)
    assert int((~m.is_end_site).sum()) == 55
    assert m.n_frames == 69 and m.rate_hz == 30.0
    assert set(m.rotation_orders()) - {""} == {"ZYX"}
    assert all(n.startswith("mixamorig:") for n in m.names)
    assert m.scale == 0.01 and any("cm -> m" in c for c in m.conversions)


def test_explicit_scale_wins(shared_data):
    m = read_bvh(shared_data / MIXAMO, scale=0.02)
    assert m.scale == 0.02 and "given" in m.conversions[0]


@pytest.mark.parametrize("rel", [CMU, MIXAMO])
def test_fk_bone_lengths_constant_and_equal_offsets(shared_data, rel):
    """Rigid bones: |child - parent| == |offset| * scale on every frame."""
    m = read_bvh(shared_data / rel)
    pos, quat = m.forward_kinematics()
    assert pos.shape == (m.n_frames, m.n_joints, 3) and quat.shape == (m.n_frames, m.n_joints, 4)
    for j in range(1, m.n_joints):
        if any(c.endswith("position") for c in m.channels[j]):
            continue
        d = np.linalg.norm(pos[:, j] - pos[:, m.parents[j]], axis=1)
        assert np.allclose(d, np.linalg.norm(m.offsets[j]) * m.scale, atol=1e-9), m.names[j]
    assert np.allclose(np.linalg.norm(quat, axis=2), 1.0)


@pytest.mark.parametrize("rel", [CMU, MIXAMO])
def test_fk_human_shape_in_world(shared_data, rel):
    m = read_bvh(shared_data / rel)
    pos, _ = m.forward_kinematics()
    names = [n.split(":")[-1] for n in m.names]
    head = pos[:, names.index("Head")]
    toe = pos[:, names.index("LeftToe" if "LeftToe" in names else "LeftToeBase")]
    # Z up, and metres: head 1.1-1.9 m above the toes
    assert 1.1 < float(np.median(head[:, 2] - toe[:, 2])) < 1.9
    # rest pose: character's left is world +Y, faces +X (toes ahead of ankles)
    rest = m.rest_positions()
    left = names.index("LeftUpLeg" if "LeftUpLeg" in names else "LeftHip")
    right = names.index("RightUpLeg" if "RightUpLeg" in names else "RightHip")
    assert rest[left, 1] > 0.03 and rest[right, 1] < -0.03
    ankle = names.index("LeftFoot" if "LeftFoot" in names else "LeftAnkle")
    assert rest[names.index("LeftToe" if "LeftToe" in names else "LeftToeBase"), 0] > rest[ankle, 0]


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


CHAIN = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT thigh
  {
    OFFSET 1 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT shin
    {
      OFFSET 0 -2 0
      CHANNELS 3 Xrotation Yrotation Zrotation
      End Site
      {
        OFFSET 0 0 3
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.01
10 20 30 0 0 0 0 0 0 0 0 0
1 2 3 90 0 0 0 0 30 45 -20 10
"""


def test_fk_against_hand_computed_chain(tmp_path):
    p = tmp_path / "chain.bvh"
    p.write_text(CHAIN)
    m = read_bvh(p, scale=0.5)
    pos, quat = m.forward_kinematics()
    d = np.deg2rad
    # frame 0: no rotation, root translated
    root0 = np.array([10.0, 20, 30])
    exp0 = [root0, root0 + [1, 0, 0], root0 + [1, -2, 0], root0 + [1, -2, 3]]
    # frame 1, written out with explicit matrices in each joint's channel order
    R0 = _rz(d(90)) @ _ry(d(0)) @ _rx(d(0))
    R1 = R0 @ (_rz(d(0)) @ _rx(d(0)) @ _ry(d(30)))
    R2 = R1 @ (_rx(d(45)) @ _ry(d(-20)) @ _rz(d(10)))
    r = np.array([1.0, 2, 3])
    j1 = r + R0 @ [1, 0, 0]
    j2 = j1 + R1 @ [0, -2, 0]
    j3 = j2 + R2 @ [0, 0, 3]
    for t, exp in ((0, exp0), (1, [r, j1, j2, j3])):
        world = (BVH_TO_WORLD @ np.array(exp).T).T * 0.5
        assert np.allclose(pos[t], world, atol=1e-12)
    # orientation of the shin in the world: A R2 A^T
    want = Rotation.from_matrix(BVH_TO_WORLD @ R2 @ BVH_TO_WORLD.T).as_quat(scalar_first=True)
    got = quat[1, 2]
    assert np.allclose(got, want) or np.allclose(got, -want)
    # world axes: BVH (x, y, z) -> world (z, x, y); frame 0 thigh offset +x_bvh = world +Y
    assert np.allclose(pos[0, 1] - pos[0, 0], [0, 0.5, 0])


def test_write_read_round_trip(shared_data, tmp_path):
    m = read_bvh(shared_data / CMU)
    out = tmp_path / "copy.bvh"
    write_bvh(out, m)
    back = read_bvh(out)
    assert back.names == m.names and back.channels == m.channels
    assert np.array_equal(back.parents, m.parents)
    assert np.allclose(back.offsets, m.offsets) and np.allclose(back.values, m.values, atol=1e-6)
    assert back.rate_hz == m.rate_hz and back.scale == m.scale
    p0, _ = m.forward_kinematics(slice(0, 50))
    p1, _ = back.forward_kinematics(slice(0, 50))
    assert np.allclose(p0, p1, atol=1e-6)


def test_to_skeleton(shared_data):
    m = read_bvh(shared_data / CMU)
    sk = bvh_to_skeleton(m, include_end_sites=False)
    assert sk.n_joints == 31 and sk.n_frames == 994 and sk.rate_hz == 120.0
    assert sk.parents[0] == -1 and all(sk.parents[1:] >= 0)
    assert sk.timestamps_ns[1] == 8_333_333 and sk.timestamps_ns.dtype == np.int64
    assert (sk.tracking_state == 2).all()
    pos, quat = m.forward_kinematics()
    keep = np.flatnonzero(~m.is_end_site)
    assert np.allclose(sk.positions, pos[:, keep]) and np.allclose(sk.orientations, quat[:, keep])
    # bone lengths constant over time from the SkeletonTrial side too
    bl = sk.bone_lengths()
    assert np.max(np.std(bl[:, 1:], axis=0)) < 1e-9


@pytest.mark.parametrize("text, fault", [
    ("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Wrotation\n}\n"
     "MOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3\n", "bad channels"),
    ("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n"
     "MOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3\n", "unbalanced"),
    ("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
     "MOTION\nFrames: 3\nFrame Time: 0.1\n1 2 3\n4 5 6\n", "truncated"),
    ("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n}\n"
     "MOTION\nFrames: 1\nFrame Time: 0.1\n1 2\n", "not a multiple"),
    ("ROOT a\n", "no MOTION"),
])
def test_broken_bvh(tmp_path, text, fault):
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(FormatError) as exc:
        read_bvh(p)
    assert str(exc.value).startswith("bad.bvh: ") and "\n" not in str(exc.value)
    assert fault in str(exc.value)
