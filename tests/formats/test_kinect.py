"""Kinect v2 body CSV reader on the LabanotationSuite captures, and the joint tables."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats.errors import FormatError
from mocapgraph.formats.kinect_csv import (KINECT_V1_JOINTS, KINECT_V1_PARENTS, KINECT_V2_JOINTS,
                                           KINECT_V2_PARENTS, read_kinect_csv)
from mocapgraph.formats.skeleton_trial import SkeletonTrial

FILES = {"Ges01_wavehand.csv": 154, "Ges02_balancinghands.csv": 161,
         "Ges03_drawlines.csv": 213, "Ges04_comehere.csv": 172, "Ges05_demopoint.csv": 190}


def test_joint_tables():
    assert len(KINECT_V2_JOINTS) == len(KINECT_V2_PARENTS) == 25
    assert len(KINECT_V1_JOINTS) == len(KINECT_V1_PARENTS) == 20
    for names, parents in ((KINECT_V2_JOINTS, KINECT_V2_PARENTS),
                           (KINECT_V1_JOINTS, KINECT_V1_PARENTS)):
        assert list(parents).count(-1) == 1
        sk = SkeletonTrial(list(names), np.array(parents), np.zeros((1, len(names), 3)),
                           np.zeros((1, len(names))), np.zeros(1), 30.0)
        order = list(sk.topological_order)
        assert all(order.index(p) < order.index(j) for j, p in enumerate(parents) if p >= 0)
    v2 = dict(zip(KINECT_V2_JOINTS, KINECT_V2_PARENTS))
    assert KINECT_V2_JOINTS[v2["Neck"]] == "SpineShoulder"
    assert KINECT_V2_JOINTS[v2["ThumbLeft"]] == "WristLeft"
    assert KINECT_V2_JOINTS[v2["HandTipRight"]] == "HandRight"


@pytest.mark.parametrize("name, frames", sorted(FILES.items()))
def test_real_files(shared_data, name, frames):
    path = shared_data / "kinect2" / name
    sk = read_kinect_csv(path)
    assert sk.n_frames == frames and sk.n_joints == 25
    assert sk.names == list(KINECT_V2_JOINTS)
    assert 29.0 < sk.rate_hz < 31.0
    first_ticks = int(path.read_text().split(",", 1)[0])
    assert sk.timestamps_ns[0] == first_ticks * 100 and sk.timestamps_ns.dtype == np.int64
    assert np.all(np.diff(sk.timestamps_ns) > 0)
    assert set(np.unique(sk.tracking_state)) <= {0, 1, 2}
    assert np.isnan(sk.positions[sk.tracking_state == 0]).all()
    # world: Z up, person facing +X, left = +Y
    assert np.all(sk.joint("Head")[:, 2] > sk.joint("SpineBase")[:, 2])
    assert np.mean(sk.joint("ShoulderLeft")[:, 1] > sk.joint("ShoulderRight")[:, 1]) > 0.95
    # person stands about 2.7 m in front of the sensor, i.e. behind the origin along X
    assert -3.2 < float(np.median(sk.joint("SpineBase")[:, 0])) < -2.0
    # bone lengths in metres: upper arm and shin of an adult
    bl = sk.bone_lengths()
    assert 0.18 < np.nanmedian(bl[:, KINECT_V2_JOINTS.index("ElbowLeft")]) < 0.38
    assert 0.25 < np.nanmedian(bl[:, KINECT_V2_JOINTS.index("AnkleLeft")]) < 0.50


def test_inferred_joints_counted(shared_data):
    sk = read_kinect_csv(shared_data / "kinect2" / "Ges01_wavehand.csv")
    assert int((sk.tracking_state == 1).sum()) == 13
    assert any("dropped" in n for n in sk.notes)


def test_ground_from_feet(shared_data):
    sk = read_kinect_csv(shared_data / "kinect2" / "Ges01_wavehand.csv", ground="feet")
    feet = sk.positions[:, [KINECT_V2_JOINTS.index("FootLeft"), KINECT_V2_JOINTS.index("FootRight")], 2]
    assert abs(float(np.nanpercentile(feet, 5))) < 0.06
    assert 1.3 < float(np.nanmedian(sk.joint("Head")[:, 2])) < 1.9


def test_not_tracked_and_v1(tmp_path):
    row = [123456789] + [v for j in range(20) for v in (0.1 * j, 1.0, 2.0, 2 if j else 0)]
    p = tmp_path / "v1.csv"
    p.write_text(",".join(map(str, row)) + ",\n" + ",".join(map(str, [row[0] + 333333] + row[1:])))
    sk = read_kinect_csv(p)
    assert sk.names == list(KINECT_V1_JOINTS) and sk.n_frames == 2
    assert np.isnan(sk.positions[:, 0]).all() and sk.tracking_state[0, 0] == 0
    # camera (x, y, z) = (0.1, 1, 2) -> world (-z, -x, y) = (-2, -0.1, 1)
    assert np.allclose(sk.positions[0, 1], [-2.0, -0.1, 1.0])
    assert sk.rate_hz == pytest.approx(30.0, rel=1e-5)


@pytest.mark.parametrize("text, fault", [("1,2,3\n", "fields"),
                                         ("", "no frames"),
                                         ("1" + ",0,0,0,2" * 25 + "\n2" + ",0,0,0,2" * 24 + "\n",
                                          "line 2"),
                                         ("1" + ",0,0,0,7" * 25 + "\n", "tracking state")])
def test_broken_csv(tmp_path, text, fault):
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(FormatError) as exc:
        read_kinect_csv(p)
    assert str(exc.value).startswith("bad.csv: ") and fault in str(exc.value)
