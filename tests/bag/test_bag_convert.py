"""Files of ../shared/data converted to bags and back: positions identical within float precision."""
from __future__ import annotations

import csv

import numpy as np
import pytest

from mocapgraph.bag.convert import bag_to_file, bag_to_marker_trial, file_to_bag
from mocapgraph.bag.reader import BagReader
from mocapgraph.formats.bvh_file import read_bvh
from mocapgraph.formats.c3d_file import read_c3d
from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.formats.trc_file import read_trc

MARKER_FILES = ["c3d/pycgm/Movement_trial.c3d", "c3d/ezc3d-testFiles/BTS.c3d", "c3d/ezc3d-testFiles/FP_Type1.c3d",
                "trc/opensim-gait2392/subject01_walk1.trc"]


def read_markers(path):
    return read_c3d(path) if str(path).endswith(".c3d") else read_trc(path)


def same_positions(a, b, rtol):
    assert np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    scale = np.maximum(np.abs(a[ok]), 1e-3)
    assert np.all(np.abs(a[ok] - b[ok]) <= rtol * scale + 1e-9)


@pytest.mark.parametrize("rel", MARKER_FILES)
def test_marker_files_through_a_bag_and_back(tmp_path, shared_data, rel):
    src = shared_data / rel
    original = read_markers(src)
    bag = tmp_path / "m.mcap"
    rep = file_to_bag(src, bag)
    assert rep.topics == {"marker_layout": 1, "markers": original.n_frames}
    with BagReader(bag) as r:
        trial = bag_to_marker_trial(r)
        stamps = trial.extra["capture_ns"]
    # in the bag: exactly the reader's float64 metres, labels, rate, frame numbers, file frame times
    assert trial.labels == original.labels and trial.rate_hz == original.rate_hz
    assert trial.first_frame == original.first_frame
    assert np.array_equal(trial.positions, original.positions, equal_nan=True)
    times = original.extra.get("time_s")
    want = (np.round((times - times[0]) * 1e9) if times is not None else original.timestamps_ns).astype(np.int64)
    assert np.array_equal(stamps, want)
    # and out again to each marker format: float32 C3D, 6-decimal mm TRC
    for ext, rtol in ((".c3d", 1e-6), (".trc", 1e-6)):
        out = tmp_path / f"back{ext}"
        bag_to_file(bag, out)
        back = read_markers(out)
        assert back.labels == original.labels and back.rate_hz == pytest.approx(original.rate_hz)
        same_positions(original.positions, back.positions, rtol)


def test_bag_to_csv_columns_named_after_labels(tmp_path, shared_data):
    src = shared_data / "trc/opensim-gait2392/subject01_walk1.trc"
    original = read_trc(src)
    file_to_bag(src, tmp_path / "w.mcap")
    bag_to_file(tmp_path / "w.mcap", tmp_path / "w.csv")
    with open(tmp_path / "w.csv") as f:
        rows = list(csv.reader(f))
    head = rows[0]
    assert len(rows) == original.n_frames + 1
    lab = original.labels[3]
    col = head.index(f"positions_{lab}_z")
    assert float(rows[11][col]) == original.positions[10, 3, 2]
    assert float(rows[11][0]) == pytest.approx(original.extra["time_s"][10] - original.extra["time_s"][0])


@pytest.mark.parametrize("rel", ["bvh/cmu/131_01.bvh", "bvh/mixamo/test_freebvh.bvh"])
def test_bvh_through_a_bag_and_back(tmp_path, shared_data, rel):
    src = shared_data / rel
    motion = read_bvh(src)
    pos, quat = motion.forward_kinematics()
    file_to_bag(src, tmp_path / "b.mcap")
    with BagReader(tmp_path / "b.mcap") as r:
        poses = [m for _, m in r.decoded("skeleton_pose")]
        info = next(m for _, m in r.decoded("skeleton_info"))
    assert info.joint_names == motion.names and len(poses) == motion.n_frames
    assert np.array_equal(poses[7].joint_positions, pos[7])
    bag_to_file(tmp_path / "b.mcap", tmp_path / "back.bvh")
    back = read_bvh(tmp_path / "back.bvh")
    assert back.rate_hz == pytest.approx(motion.rate_hz, rel=1e-6)
    idx = [back.names.index(n) for n in motion.names]
    p2, q2 = back.forward_kinematics()
    assert np.abs(p2[:, idx] - pos).max() < 1e-6  # metres; the file holds 6 decimals of cm
    dots = np.abs(np.einsum("tjk,tjk->tj", q2[:, idx], quat))
    assert dots.min() > 1 - 1e-9


def test_kinect_csv_into_a_bag(tmp_path, shared_data):
    src = sorted((shared_data / "kinect2").glob("*.csv"))[0]
    trial = read_kinect_csv(src)
    file_to_bag(src, tmp_path / "k.mcap")
    with BagReader(tmp_path / "k.mcap") as r:
        got = list(r.decoded("skeleton_pose"))
        info = next(m for _, m in r.decoded("skeleton_info"))
    assert info.joint_names == trial.names and info.source == "kinect_csv"
    assert np.array_equal(np.stack([m.joint_positions for _, m in got]), trial.positions, equal_nan=True)
    assert np.array_equal(np.stack([m.tracking_state for _, m in got]), trial.tracking_state)
    stamps = np.array([e.capture_ns for e, _ in got])
    assert np.array_equal(stamps, trial.timestamps_ns - trial.timestamps_ns[0])  # the sensor's frame times


def test_character_poses_to_bvh(tmp_path, shared_data):
    from scipy.spatial.transform import Rotation

    from mocapgraph.bag.writer import BagWriter
    from mocapgraph.messages import CharacterInfo, CharacterPose

    motion = read_bvh(shared_data / "bvh/mixamo/test_freebvh.bvh")
    pos, quat = motion.forward_kinematics()
    rest = motion.rest_positions()
    par = motion.parents
    off = rest.copy()
    off[par >= 0] = rest[par >= 0] - rest[par[par >= 0]]
    R = Rotation.from_quat(quat.reshape(-1, 4), scalar_first=True).as_matrix().reshape(*quat.shape[:2], 3, 3)
    parent_R = np.where((par >= 0)[None, :, None, None], R[:, np.maximum(par, 0)], np.eye(3))
    local = np.einsum("tjki,tjkl->tjil", parent_R, R)  # CharacterPose: rotation relative to the parent
    lq = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_quat(scalar_first=True).reshape(quat.shape)
    with BagWriter(tmp_path / "c.mcap") as w:
        w.write("character_info", CharacterInfo(character="mixamo", joint_names=motion.names, joint_parent=par,
                                                rest_offsets=off, rest_rotations=np.tile([1.0, 0, 0, 0], (len(par), 1))),
                seq=1, capture_ns=0)
        for t in range(motion.n_frames):
            w.write("character_pose", CharacterPose(character="mixamo", frame_number=t, root_position=pos[t, 0],
                                                    local_rotations=lq[t], joint_positions=pos[t],
                                                    joint_quality=np.full(len(par), 2, np.int8)),
                    seq=t + 1, capture_ns=int(t * motion.frame_time_s * 1e9))
    rep = bag_to_file(tmp_path / "c.mcap", tmp_path / "c.bvh")
    assert rep.topics == {"character_pose": motion.n_frames}
    back = read_bvh(tmp_path / "c.bvh")
    idx = [back.names.index(n) for n in motion.names]
    assert np.abs(back.forward_kinematics()[0][:, idx] - pos).max() < 1e-6
