"""Every shared capture still reads as the data README describes it (frames, rate, units, axes)
after the issue-11 reader fixes, and goes through ``bag convert`` and back unchanged."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.bag.convert import bag_to_file, bag_to_marker_trial, bag_to_skeleton_frames, file_to_bag
from mocapgraph.bag.errors import BagError
from mocapgraph.bag.reader import BagReader
from mocapgraph.formats import (FormatError, bvh_to_skeleton, read_bvh, read_c3d, read_kinect_csv, read_markers)

# (file, frames, rate Hz, markers, the unit conversion, file up axis): ../shared/data/README.md
MARKERS = [
    ("c3d/pycgm/Static_trial.c3d", 498, 120.0, 39, "units mm -> m", "+Z"),
    ("c3d/pycgm/Movement_trial.c3d", 323, 120.0, 39, "units mm -> m", "+Z"),
    ("c3d/ezc3d-testFiles/Qualisys.c3d", 340, 200.0, 55, "units mm -> m", "+Z"),
    ("c3d/ezc3d-testFiles/BTS.c3d", 675, 100.0, 22, "units mm -> m", "+Y"),
    ("c3d/ezc3d-testFiles/FP_Type1.c3d", 634, 100.0, 22, None, "+Y"),          # already metres
    ("c3d/btkdata/golfswing.c3d", 514, 107.5, 29, "units mm -> m", "+Z"),
    ("trc/opensim-gait2392/subject01_static.trc", 300, 60.0, 49, "units mm -> m", "+Y"),
    ("trc/opensim-gait2392/subject01_walk1.trc", 151, 60.0, 41, "units mm -> m", "+Y"),
]


def close(a: np.ndarray, b: np.ndarray, rtol: float) -> None:
    assert np.array_equal(np.isnan(a), np.isnan(b))
    ok = ~np.isnan(a)
    assert np.all(np.abs(a[ok] - b[ok]) <= rtol * np.maximum(np.abs(a[ok]), 1e-3) + 1e-9)


@pytest.mark.parametrize("rel, frames, rate, markers, unit, up", MARKERS)
def test_marker_capture_reads_as_documented_and_round_trips(shared_data, tmp_path, rel, frames, rate, markers,
                                                            unit, up) -> None:
    src = shared_data / rel
    tr = read_markers(src)
    assert (tr.n_frames, tr.n_markers) == (frames, markers)
    assert tr.rate_hz == pytest.approx(rate, abs=0.05)
    assert tr.extra["file_up"] == up
    assert (unit in tr.conversions) if unit else not any(c.startswith("units") for c in tr.conversions)
    assert len(set(map(str.lower, tr.labels))) == markers          # no duplicate renamed in these
    rep = file_to_bag(src, tmp_path / "m.mcap")
    assert rep.topics == {"marker_layout": 1, "markers": frames}
    with BagReader(tmp_path / "m.mcap") as r:
        inside = bag_to_marker_trial(r)
    assert inside.labels == tr.labels and np.array_equal(inside.positions, tr.positions, equal_nan=True)
    out = tmp_path / ("back" + src.suffix)
    bag_to_file(tmp_path / "m.mcap", out)
    back = read_markers(out)
    assert back.labels == tr.labels and back.n_frames == frames and back.first_frame == tr.first_frame
    close(tr.positions, back.positions, 1e-6)
    # OpenSim's Time column is rounded to 1 ms (0.017 for 1/60 s): that rounding is all that differs
    np.testing.assert_allclose(back.file_times_s - back.file_times_s[0], tr.file_times_s - tr.file_times_s[0],
                               atol=5e-4)


@pytest.mark.parametrize("rel, frames, rate, joints", [("bvh/cmu/131_01.bvh", 994, 120.0, 38),
                                                       ("bvh/mixamo/test_freebvh.bvh", 69, 30.0, 70)])
def test_bvh_capture_reads_as_documented_and_round_trips(shared_data, tmp_path, rel, frames, rate, joints) -> None:
    m = read_bvh(shared_data / rel)
    assert (m.n_frames, m.n_joints, m.rate_hz) == (frames, joints, rate)
    pos, quat = m.forward_kinematics()
    assert np.allclose(m.offsets[0], 0.0)       # both roots sit at 0: the offset rule changes nothing here
    file_to_bag(shared_data / rel, tmp_path / "b.mcap")
    bag_to_file(tmp_path / "b.mcap", tmp_path / "back.bvh")
    back = read_bvh(tmp_path / "back.bvh")
    idx = [back.names.index(n) for n in m.names]
    assert np.abs(back.forward_kinematics()[0][:, idx] - pos).max() < 1e-6


@pytest.mark.parametrize("name", ["Ges01_wavehand", "Ges02_balancinghands", "Ges03_drawlines", "Ges04_comehere",
                                  "Ges05_demopoint"])
def test_kinect_capture_reads_as_documented_and_round_trips(shared_data, tmp_path, name) -> None:
    src = shared_data / "kinect2" / f"{name}.csv"
    tr = read_kinect_csv(src)
    assert tr.n_joints == 25 and 29.5 < tr.rate_hz < 31.0
    assert tr.extra["behind_sensor"] == 0    # real recordings: nothing behind the sensor
    file_to_bag(src, tmp_path / "k.mcap")
    with BagReader(tmp_path / "k.mcap") as r:
        sk = bag_to_skeleton_frames(r)
    assert sk.names == tr.names and np.array_equal(sk.positions, tr.positions, equal_nan=True)


def test_broken_capture_still_fails_in_one_line(shared_data, tmp_path) -> None:
    src = shared_data / "c3d/btkdata/mocap36.c3d"
    with pytest.raises(FormatError) as e:
        read_c3d(src)
    with pytest.raises(BagError) as b:
        file_to_bag(src, tmp_path / "x.mcap")
    assert "\n" not in str(e.value) and str(e.value).startswith("mocap36.c3d: POINT:LABELS parameter is broken")
    assert "\n" not in str(b.value) and str(b.value).endswith(e.value.fault)
