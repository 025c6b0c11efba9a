"""One "file -> frames" path (formats.sources, bag.sources) for the bag converter and the batch commands,
checked against each format's own reader on the captures of ../shared/data and a bag made from one."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.bag.convert import file_to_bag
from mocapgraph.bag.errors import BagError
from mocapgraph.bag.sources import read_marker_input
from mocapgraph.bag.trial_frames import read_trial_frames as read_source
from mocapgraph.formats.bvh_file import bvh_to_skeleton, read_bvh
from mocapgraph.formats.c3d_file import read_c3d
from mocapgraph.formats.errors import FormatError
from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.kinematics.rest_offsets import offsets_from_rest
from mocapgraph.formats.sources import file_kind, read_skeleton_file, skeleton_rest_offsets
from mocapgraph.formats.trc_file import read_trc


def test_a_bvh_reads_as_its_reader_gives_with_its_rest_pose(shared_data) -> None:
    path = shared_data / "bvh" / "cmu" / "131_01.bvh"
    motion = read_bvh(path)
    want = bvh_to_skeleton(motion, start_ns=0)
    got = read_skeleton_file(path)
    assert got.names == want.names and file_kind(path) == "bvh"
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.orientations, want.orientations)
    np.testing.assert_array_equal(got.timestamps_ns, want.timestamps_ns)
    np.testing.assert_array_equal(skeleton_rest_offsets(got), offsets_from_rest(motion.rest_positions(), want.parents))
    # the retarget command's source: the same offsets and frames
    frames = read_source(str(path), None, None)
    np.testing.assert_array_equal(frames.points, want.positions)
    np.testing.assert_allclose(frames.times_s, np.arange(motion.n_frames) / motion.rate_hz)


def test_a_kinect_csv_is_stamped_from_its_first_frame(shared_data) -> None:
    path = shared_data / "kinect2" / "Ges04_comehere.csv"
    want = read_kinect_csv(path, ground="feet")
    got = read_skeleton_file(path, ground="feet")
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.tracking_state, want.tracking_state)
    np.testing.assert_array_equal(got.timestamps_ns, want.timestamps_ns - want.timestamps_ns[0])
    assert got.timestamps_ns[0] == 0 and file_kind(path.with_suffix(".txt")) == "kinect_csv"


@pytest.mark.parametrize("rel", ["trc/opensim-gait2392/subject01_walk1.trc", "c3d/pycgm/Movement_trial.c3d"])
def test_a_marker_file_reads_as_its_reader_gives(shared_data, rel) -> None:
    path = shared_data / rel
    want = read_trc(path, up_axis="auto") if rel.endswith(".trc") else read_c3d(path, up_axis="auto")
    got = read_marker_input(path)
    assert got.labels == list(want.labels) and got.rate_hz == want.rate_hz and got.layout_name == ""
    np.testing.assert_array_equal(got.positions, want.positions)
    np.testing.assert_array_equal(got.frame_numbers, want.first_frame + np.arange(want.n_frames))
    np.testing.assert_array_equal(got.times(), want.file_times_s)


def test_a_bag_of_markers_reads_back_the_file_it_was_made_from(shared_data, tmp_path) -> None:
    src = shared_data / "trc" / "opensim-gait2392" / "subject01_walk1.trc"
    file_to_bag(src, tmp_path / "m.mcap")
    got = read_marker_input(tmp_path / "m.mcap")
    want = read_trc(src)
    assert got.labels == list(want.labels) and got.layout_name == "subject01_walk1"
    np.testing.assert_allclose(got.positions, want.positions, rtol=1e-6)
    np.testing.assert_allclose(got.times(), (np.arange(want.n_frames)) / want.rate_hz)
    with pytest.raises(BagError, match="already in world axes"):
        read_marker_input(tmp_path / "m.mcap", up_axis="y")


def test_other_files_are_refused_in_one_line(tmp_path) -> None:
    odd = tmp_path / "x.dat"
    odd.write_text("1 2 3\n")
    assert file_kind(odd) is None
    with pytest.raises(FormatError, match="not a skeleton file"):
        read_skeleton_file(odd)
    with pytest.raises(FormatError, match="unknown marker file type"):
        read_marker_input(odd)
