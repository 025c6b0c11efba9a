"""C3D reader/writer against the real captures in ../shared/data/c3d."""
from __future__ import annotations

import time

import numpy as np
import pytest

from mocapgraph.formats.c3d_file import inspect_c3d, read_c3d, write_c3d
from mocapgraph.formats.errors import FormatError


def _one_line(err: FormatError, name: str) -> str:
    msg = str(err)
    assert "\n" not in msg
    assert msg.startswith(name + ": ")
    return msg


@pytest.mark.parametrize("rel, markers, frames, rate, first", [
    ("c3d/pycgm/Static_trial.c3d", 39, 498, 120.0, 1),
    ("c3d/pycgm/Movement_trial.c3d", 39, 323, 120.0, 695),
    ("c3d/ezc3d-testFiles/Qualisys.c3d", 55, 340, 200.0, 705),
    ("c3d/ezc3d-testFiles/BTS.c3d", 22, 675, 100.0, 1),
    ("c3d/ezc3d-testFiles/FP_Type1.c3d", 22, 634, 100.0, 1),
    ("c3d/btkdata/golfswing.c3d", 29, 514, 107.5, 1),
])
def test_real_files_counts_rate_frames(shared_data, rel, markers, frames, rate, first):
    tr = read_c3d(shared_data / rel)
    assert tr.n_markers == markers
    assert tr.n_frames == frames
    assert tr.rate_hz == pytest.approx(rate, abs=0.05)
    assert tr.first_frame == first
    assert tr.positions.shape == (frames, markers, 3)
    assert tr.residuals.shape == (frames, markers)
    assert not np.any(np.all(tr.positions == 0.0, axis=2)), "zero-coded points must be NaN"


def _stature(tr, top, bottom):
    """Vertical distance (world Z) from a head marker to a foot marker, median over frames."""
    return float(np.nanmedian(tr.marker(top)[:, 2] - tr.marker(bottom)[:, 2]))


def test_vicon_static_units_and_axes(shared_data):
    tr = read_c3d(shared_data / "c3d/pycgm/Static_trial.c3d")
    assert "units mm -> m" in tr.conversions
    # Test.vsk: subject height 1679 mm; forehead marker to heel is a bit less
    assert 1.4 < _stature(tr, "LFHD", "LHEE") < 1.75
    # Z-up file: no axis conversion
    assert np.allclose(tr.extra["file_to_world"], np.eye(3))
    # left markers on +Y side of right markers (lab X forward, right-handed): not assumed,
    # but the pelvis width must be horizontal
    d = np.nanmedian(tr.marker("LASI") - tr.marker("RASI"), axis=0)
    assert abs(d[2]) < 0.05 and 0.18 < np.linalg.norm(d) < 0.32


def test_vicon_unlabelled_and_model_outputs(shared_data):
    path = shared_data / "c3d/pycgm/Static_trial.c3d"
    tr = read_c3d(path)
    assert not any(lab.startswith("*") for lab in tr.labels)
    assert tr.extra["n_unlabelled"] == 38
    assert "LFEO" not in tr.labels and "LHipAngles" not in tr.labels
    assert tr.model_output_kinds["LFEO"] == "position [m, world]"
    assert tr.model_output_kinds["LHipAngles"].startswith("angle [rad")
    assert tr.model_outputs["LFEO"].shape == (498, 3)
    # angles converted to radians: hip angles in a static pose are well under 90 degrees
    assert np.nanmax(np.abs(tr.model_outputs["LHipAngles"])) < np.pi / 2
    everything = read_c3d(path, include_unlabelled=True, include_model_outputs=True)
    assert everything.n_markers == 179


def test_movement_same_marker_set_and_vicon_knee_ankle(shared_data):
    static = read_c3d(shared_data / "c3d/pycgm/Static_trial.c3d")
    move = read_c3d(shared_data / "c3d/pycgm/Movement_trial.c3d")
    assert set(static.labels) == set(move.labels)
    assert static.labels != move.labels  # different order in the file, as the README says
    # README: Vicon's knee-ankle distance ranges 314-389 mm: the left femur and tibia segment
    # origins (knee and ankle joint centres), read as model outputs and converted to metres
    d = np.linalg.norm(move.model_outputs["LFEO"] - move.model_outputs["LTIO"], axis=1)
    assert np.nanmin(d) == pytest.approx(0.314, abs=0.001)
    assert np.nanmax(d) == pytest.approx(0.389, abs=0.001)


def test_bts_gaps_are_nan_and_y_up_converted(shared_data):
    tr = read_c3d(shared_data / "c3d/ezc3d-testFiles/BTS.c3d")
    assert 0.50 < tr.gap_fraction < 0.54  # README: 52 % gaps
    miss = ~tr.valid
    assert np.isnan(tr.positions[miss]).all() and np.isnan(tr.residuals[miss]).all()
    assert "r should" in tr.labels  # lower-case names with spaces kept
    assert any("Y-up -> Z-up" in c for c in tr.conversions)
    assert 1.1 < _stature(tr, "c7", "r heel") < 1.7


def test_fp_type1_metres_not_scaled_twice(shared_data):
    tr = read_c3d(shared_data / "c3d/ezc3d-testFiles/FP_Type1.c3d")
    assert not any("units" in c for c in tr.conversions)
    # c7 to heel of an adult standing: metres, not millimetres or micrometres
    assert 1.2 < _stature(tr, "c7", "r heel") < 1.7
    assert 0.8 < float(np.nanmedian(tr.marker("sacrum")[:, 2])) < 1.2


def test_qualisys_declared_minus_z_up_is_corrected(shared_data):
    tr = read_c3d(shared_data / "c3d/ezc3d-testFiles/Qualisys.c3d")
    assert any("Y_SCREEN" in n for n in tr.notes)
    assert 1.2 < _stature(tr, "L_HDF", "L_FCC") < 1.8
    # the same file, forced to believe Y_SCREEN's sign, is upside down
    flipped = read_c3d(shared_data / "c3d/ezc3d-testFiles/Qualisys.c3d", up_axis="-Z")
    assert _stature(flipped, "L_HDF", "L_FCC") < -1.2


def test_golfswing_needs_the_fallback(shared_data):
    tr = read_c3d(shared_data / "c3d/btkdata/golfswing.c3d")
    assert tr.extra["backend"] == "c3d"
    assert any("ezc3d refused" in n for n in tr.notes)
    assert any(n.startswith("c3d package:") for n in tr.notes)
    assert all(lab.startswith("Channel") for lab in tr.labels)


@pytest.mark.timing  # a wall-clock bound (a hang or a quadratic path fails it)
def test_mocap36_refused_with_one_line(shared_data):
    t0 = time.monotonic()
    with pytest.raises(FormatError) as exc:
        read_c3d(shared_data / "c3d/btkdata/mocap36.c3d")
    assert time.monotonic() - t0 < 2.0
    msg = _one_line(exc.value, "mocap36.c3d")
    assert "POINT:LABELS parameter is broken" in msg


@pytest.mark.timing  # a wall-clock bound (a hang or a quadratic path fails it)
@pytest.mark.parametrize("keep", [100, 600, 5000, 20000, 0.5, -100])
def test_truncated_file_fails_fast(shared_data, tmp_path, keep):
    src = (shared_data / "c3d/pycgm/Static_trial.c3d").read_bytes()
    n = int(len(src) * keep) if isinstance(keep, float) else keep % len(src)
    cut = tmp_path / "cut.c3d"
    cut.write_bytes(src[:n])
    t0 = time.monotonic()
    with pytest.raises(FormatError) as exc:
        read_c3d(cut)
    assert time.monotonic() - t0 < 2.0  # ezc3d alone spends ~20 s on some of these
    msg = _one_line(exc.value, "cut.c3d")
    assert "truncated" in msg or "not a C3D" in msg


def test_not_a_c3d(tmp_path):
    p = tmp_path / "junk.c3d"
    p.write_bytes(b"hello" * 300)
    with pytest.raises(FormatError, match=r"^junk\.c3d: not a C3D file"):
        read_c3d(p)
    with pytest.raises(FormatError, match=r"^missing\.c3d: cannot read"):
        read_c3d(tmp_path / "missing.c3d")


def test_inspect_accepts_every_good_file(shared_data):
    for p in sorted((shared_data / "c3d").rglob("*.c3d")):
        if p.name == "mocap36.c3d":
            continue
        lay = inspect_c3d(p)
        assert "POINT:LABELS" in lay.parameters
        assert lay.frames_in_file >= lay.last_frame - lay.first_frame


def test_write_read_round_trip(shared_data, tmp_path):
    tr = read_c3d(shared_data / "c3d/ezc3d-testFiles/BTS.c3d")
    out = tmp_path / "bts_copy.c3d"
    write_c3d(out, tr)
    back = read_c3d(out)
    assert back.labels == tr.labels
    assert back.rate_hz == tr.rate_hz
    assert np.array_equal(back.valid, tr.valid)
    assert np.nanmax(np.abs(back.positions - tr.positions)) < 1e-6  # float32 mm
    assert np.allclose(back.extra["file_to_world"], np.eye(3))
