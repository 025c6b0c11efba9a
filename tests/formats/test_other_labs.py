"""Readers on files "from other labs" (issue 11): each fixture is written here, with its ground
truth, and must be read right or refused in one clear line, never a traceback or a hang."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lab_fixtures import (PERSON_LABELS, RATE, bvh_with_root_offset, cut_data, kinect_csv, person_frames,
                          set_header_last_frame, write_points_c3d)
from mocapgraph.formats import (FormatError, MarkerTrial, bvh_to_skeleton, read_bvh, read_c3d,
                                read_c3d_segments, read_kinect_csv, read_trc, write_trc)
from mocapgraph.formats.axes import optional_axis, parse_axis, up_option

# world (x, y, z) of a Y-up file's point (x, y, z)_file is (x, -z, y): the file's +Y is up
Y_UP_TO_WORLD = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])


def y_up(points_world: np.ndarray) -> np.ndarray:
    """World points as a Y-up file holds them (the inverse map)."""
    return points_world @ Y_UP_TO_WORLD  # rows: R^T v


def one_line(exc: FormatError, name: str) -> str:
    msg = str(exc)
    assert "\n" not in msg and msg.startswith(name + ": ") and "Traceback" not in msg
    return msg


# ----- axes --------------------------------------------------------------------------------------
def test_empty_or_absent_axis_is_not_given_and_garbage_is_a_value_error() -> None:
    for empty in ("", "  ", None):
        assert optional_axis(empty) is None
        assert up_option(empty) is None
    assert up_option("auto") is None and up_option("y") == "+Y" and up_option("-z") == "-Z"
    for bad in ("", "+", "-", "Q", "+XY"):
        with pytest.raises(ValueError, match="not an axis"):
            parse_axis(bad)


# ----- C3D without screen parameters, and up_axis -------------------------------------------------
@pytest.mark.parametrize("y_screen", [None, ""])
def test_c3d_without_y_screen_reads_z_up_with_a_note(tmp_path, y_screen) -> None:
    truth = person_frames(20)
    path = write_points_c3d(tmp_path / "vendor_a_static.c3d", PERSON_LABELS, truth, y_screen=y_screen)
    tr = read_c3d(path)
    np.testing.assert_allclose(tr.positions, truth, atol=1e-6)
    assert tr.extra["file_up"] == "+Z"
    assert any("no usable POINT:Y_SCREEN; Z up assumed" in n for n in tr.notes)


def test_y_up_c3d_without_screen_parameters_is_read_right_with_up_axis(tmp_path) -> None:
    truth = person_frames(20)
    path = write_points_c3d(tmp_path / "vendor_b.c3d", PERSON_LABELS, y_up(truth), y_screen=None)
    wrong = read_c3d(path)
    assert np.nanmedian(wrong.marker("HEAD")[:, 2]) == pytest.approx(0.0, abs=1e-6)  # Y-up read as Z-up
    for up in ("y", "+Y", "Y"):
        tr = read_c3d(path, up_axis=up)
        np.testing.assert_allclose(tr.positions, truth, atol=1e-6)
        assert tr.extra["file_up"] == "+Y" and any("as requested" in c for c in tr.conversions)
    # a Y-up TRC exported Z-up is told the same way
    write_trc(tmp_path / "z_up.trc", read_c3d(path, up_axis="y"), up_axis="+Z")
    np.testing.assert_allclose(read_trc(tmp_path / "z_up.trc", up_axis="z").positions, truth, atol=1e-6)
    np.testing.assert_allclose(read_trc(tmp_path / "z_up.trc", up_axis="auto").positions,
                               truth @ Y_UP_TO_WORLD.T, atol=1e-6)  # auto = Y up: the wrong axes here


def test_garbage_y_screen_is_noted_and_ignored(tmp_path) -> None:
    path = write_points_c3d(tmp_path / "odd.c3d", PERSON_LABELS, person_frames(5), y_screen="Up")
    tr = read_c3d(path)
    assert tr.extra["file_up"] == "+Z" and any("'Up' names no axis" in n for n in tr.notes)


# ----- frame counts --------------------------------------------------------------------------------
def test_header_frame_count_disagreeing_with_point_frames_uses_the_parameter(tmp_path) -> None:
    truth = person_frames(29)
    path = write_points_c3d(tmp_path / "optotrak.c3d", PERSON_LABELS, truth, y_screen="+Z")
    set_header_last_frame(path, 1149)      # header promises 1149 frames, POINT:FRAMES says 29
    tr = read_c3d(path)
    assert tr.n_frames == 29 and tr.first_frame == 1
    np.testing.assert_allclose(tr.positions, truth, atol=1e-6)
    (note,) = [n for n in tr.notes if "POINT:FRAMES" in n]
    assert "header frames 1..1149 (1149) disagree with POINT:FRAMES 29; used POINT:FRAMES" in note


def test_a_cut_data_block_is_still_refused_in_one_line(tmp_path) -> None:
    path = write_points_c3d(tmp_path / "cut.c3d", PERSON_LABELS, person_frames(29), y_screen="+Z")
    cut_data(path, 10, len(PERSON_LABELS))
    with pytest.raises(FormatError) as e:
        read_c3d(path)
    assert "file is truncated: data block holds 10 of the 29 frames" in one_line(e.value, "cut.c3d")
    set_header_last_frame(path, 1149)    # and when header and POINT:FRAMES disagree as well
    with pytest.raises(FormatError) as e:
        read_c3d(path)
    assert "data block holds 10 frames, POINT:FRAMES promises 29 and the header 1149" in one_line(e.value, "cut.c3d")


# ----- duplicate labels ---------------------------------------------------------------------------
def test_duplicate_c3d_labels_are_kept_with_a_suffix_and_a_note(tmp_path) -> None:
    truth = person_frames(10)
    pts = np.concatenate([truth, truth[:, :1] + [0.0, 0.0, 0.1]], axis=1)   # a second "HEAD"
    labels = list(PERSON_LABELS) + ["head"]                                  # case differs too
    tr = read_c3d(write_points_c3d(tmp_path / "dup.c3d", labels, pts, y_screen="+Z"))
    assert tr.labels == ["HEAD", "PELV", "LFOOT", "RFOOT", "head_2"]
    np.testing.assert_allclose(tr.marker("HEAD"), truth[:, 0], atol=1e-6)       # the first keeps its name
    np.testing.assert_allclose(tr.marker("head_2"), pts[:, 4], atol=1e-6)       # nothing lost
    assert "duplicate label 'head': points 0 and 4 share it; point 4 renamed 'head_2'" in tr.notes


def test_duplicate_trc_names_too(tmp_path) -> None:
    tr = read_c3d(write_points_c3d(tmp_path / "x.c3d", ["A", "B", "C", "D"], person_frames(5), y_screen="+Z"))
    tr.labels = ["A", "B", "A", "A_2"]   # a name taken by the would-be suffix
    write_trc(tmp_path / "dup.trc", tr)
    back = read_trc(tmp_path / "dup.trc")
    assert back.labels == ["A", "B", "A_3", "A_2"]
    np.testing.assert_allclose(back.positions, tr.positions, atol=1e-6)
    assert any("markers 0 and 2 share it; marker 2 renamed 'A_3'" in n for n in back.notes)


# ----- time columns ---------------------------------------------------------------------------------
def test_file_times_keep_the_start_time(tmp_path) -> None:
    c3d = read_c3d(write_points_c3d(tmp_path / "late.c3d", PERSON_LABELS, person_frames(5), y_screen="+Z",
                                    first_frame=24))
    np.testing.assert_allclose(c3d.file_times_s, (23 + np.arange(5)) / RATE)   # frame 1 = 0 s
    zero_based = MarkerTrial(c3d.labels, c3d.positions, None, RATE, first_frame=0)
    np.testing.assert_allclose(zero_based.file_times_s, np.arange(5) / RATE)    # never negative
    c3d.extra["time_s"] = 0.23 + np.arange(5) / RATE
    write_trc(tmp_path / "late.trc", c3d)
    trc = read_trc(tmp_path / "late.trc")
    np.testing.assert_allclose(trc.file_times_s, 0.23 + np.arange(5) / RATE, atol=1e-6)
    np.testing.assert_allclose(trc.frames(2).file_times_s, 0.25 + np.arange(3) / RATE, atol=1e-6)


# ----- ROTATION group ------------------------------------------------------------------------------
def segment_poses(T: int) -> tuple[np.ndarray, list[str]]:
    """[T, 3, 4, 4] world poses (metres) of pelvis, thigh, shank; shank invalid in frame 2."""
    names = ["pelvis", "l_thigh", "l_shank"]
    rot = Rotation.from_euler("zyx", [[90, 0, 0], [10, 20, 30], [0, -45, 5]], degrees=True).as_matrix()
    poses = np.tile(np.eye(4), (T, 3, 1, 1))
    poses[:, :, :3, :3] = rot
    poses[:, :, :3, 3] = [[0.1, 0.2, 1.0], [0.1, 0.3, 0.8], [0.12, 0.3, 0.4]]
    poses[:, :, 0, 3] += (np.arange(T) / RATE)[:, None]
    poses[2, 2] = np.nan
    return poses, names


@pytest.mark.parametrize("file_up", ["z", "y"])
def test_rotation_group_reads_as_segment_poses(tmp_path, file_up) -> None:
    T = 6
    world, names = segment_poses(T)
    filed = world.copy()
    if file_up == "y":   # the same poses held by a Y-up file: R_file = A^T R, t_file = A^T t
        filed[..., :3, :3] = np.einsum("ji,tsjk->tsik", Y_UP_TO_WORLD, world[..., :3, :3])
        filed[..., :3, 3] = world[..., :3, 3] @ Y_UP_TO_WORLD
    path = write_points_c3d(tmp_path / "theia.c3d", [], np.zeros((T, 0, 3)), y_screen="+Y" if file_up == "y" else None,
                            rotations=filed, rotation_labels=names)
    sk = read_c3d_segments(path)
    assert sk.names == names and sk.n_frames == T and sk.rate_hz == RATE
    assert (sk.parents == -1).all()
    ok = np.ones((T, 3), bool)
    ok[2, 2] = False
    np.testing.assert_array_equal(sk.tracking_state, np.where(ok, 2, 0))
    np.testing.assert_allclose(sk.positions[ok], world[..., :3, 3][ok], atol=1e-6)
    assert np.isnan(sk.positions[2, 2]).all() and np.isnan(sk.orientations[2, 2]).all()
    got = Rotation.from_quat(sk.orientations[ok], scalar_first=True)
    want = Rotation.from_matrix(world[..., :3, :3][ok])
    ang = np.degrees((got.inv() * want).magnitude())
    pos_err = np.abs(sk.positions[ok] - world[..., :3, 3][ok]).max()
    print(f"\nROTATION group ({file_up}-up file) vs ground truth: position {pos_err * 1e6:.2f} um, "
          f"orientation {ang.max():.2e} deg max (float32 file)")
    assert ang.max() < 1e-3
    np.testing.assert_array_equal(sk.timestamps_ns, np.round(np.arange(T) * 1e9 / RATE).astype(np.int64))
    # as markers, the file says what it is instead of reading as 0 markers
    with pytest.raises(FormatError) as e:
        read_c3d(path)
    assert "holds no markers, only 3 segment poses in its ROTATION group" in one_line(e.value, "theia.c3d")


def test_a_file_without_rotation_group_is_refused_as_segments(tmp_path) -> None:
    path = write_points_c3d(tmp_path / "markers_only.c3d", PERSON_LABELS, person_frames(3), y_screen="+Z")
    with pytest.raises(FormatError) as e:
        read_c3d_segments(path)
    assert "has no segment poses" in one_line(e.value, "markers_only.c3d")


# ----- BVH root offset -----------------------------------------------------------------------------
def test_bvh_root_offset_with_absolute_positions_keeps_the_feet_on_the_floor(tmp_path) -> None:
    m = read_bvh(bvh_with_root_offset(tmp_path / "offset_root.bvh"), scale=0.01)
    sk = bvh_to_skeleton(m)
    z = sk.positions[..., 2]
    for end in ("LeftFoot_End", "RightFoot_End"):
        np.testing.assert_allclose(z[:, sk.index(end)], 0.0, atol=1e-9)        # on the floor
    np.testing.assert_allclose(z[:, sk.index("Hips")], 0.90, atol=1e-9)        # the channel, not 0.9 + 0.9
    np.testing.assert_allclose(z[:, sk.index("Head_End")], 1.75, atol=1e-9)
    # the rest pose is the offsets: the same standing height
    rest = m.rest_positions()
    assert rest[m.index("Hips"), 2] == pytest.approx(0.90) and rest[m.index("LeftFoot_End"), 2] == pytest.approx(0.0)
    # walking along BVH +Z (the character's facing) is world +X
    np.testing.assert_allclose(sk.positions[:, sk.index("Hips"), 0], 0.05 * np.arange(4), atol=1e-9)


def test_bvh_root_offset_without_position_channels_is_kept(tmp_path) -> None:
    text = bvh_with_root_offset(tmp_path / "a.bvh").read_text()
    text = text.replace("CHANNELS 6 Xposition Yposition Zposition Zrotation", "CHANNELS 3 Zrotation")
    rows = text.split("Frame Time: 0.0333333\n")
    motion = "\n".join(" ".join(r.split()[3:]) for r in rows[1].strip().splitlines())
    (tmp_path / "b.bvh").write_text(rows[0] + "Frame Time: 0.0333333\n" + motion + "\n")
    sk = bvh_to_skeleton(read_bvh(tmp_path / "b.bvh", scale=0.01))
    np.testing.assert_allclose(sk.positions[:, sk.index("Hips"), 2], 0.90, atol=1e-9)
    np.testing.assert_allclose(sk.positions[:, sk.index("LeftFoot_End"), 2], 0.0, atol=1e-9)


# ----- Kinect behind the sensor --------------------------------------------------------------------
def test_kinect_samples_behind_the_sensor_are_not_tracked_and_counted(tmp_path) -> None:
    behind = ((1, 3, 2), (1, 7, 1), (3, 3, 2))      # (frame, joint, state in the file)
    tr = read_kinect_csv(kinect_csv(tmp_path / "k.csv", behind=behind))
    assert tr.extra["behind_sensor"] == 3
    for f, j, _ in behind:
        assert tr.tracking_state[f, j] == 0 and np.isnan(tr.positions[f, j]).all()
    mask = np.ones(tr.tracking_state.shape, bool)
    for f, j, _ in behind:
        mask[f, j] = False
    assert (tr.tracking_state[mask] == 2).all() and np.isfinite(tr.positions[mask]).all()
    assert any("3 joint samples lie behind the sensor (camera z <= 0) in 2 frames (first on data line 2)" in n
               for n in tr.notes)
    # on the sensor itself: impossible when tracked, the SDK's "untracked" encoding when state 0
    on = read_kinect_csv(kinect_csv(tmp_path / "on.csv", behind=((0, 1, 2), (2, 4, 0)), z_behind=0.0))
    assert on.extra["behind_sensor"] == 1 and on.tracking_state[0, 1] == 0 and on.tracking_state[2, 4] == 0
    clean = read_kinect_csv(kinect_csv(tmp_path / "clean.csv"))
    assert clean.extra["behind_sensor"] == 0 and not any("behind" in n for n in clean.notes)
