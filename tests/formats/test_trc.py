"""TRC reader/writer: the OpenSim example files and the malformed variants real files have."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats.errors import FormatError
from mocapgraph.formats.marker_trial import MarkerTrial
from mocapgraph.formats.trc_file import read_trc, write_trc

GAIT = "trc/opensim-gait2392"


@pytest.mark.parametrize("name, markers, frames", [("subject01_static.trc", 49, 300),
                                                    ("subject01_walk1.trc", 41, 151)])
def test_real_files(shared_data, name, markers, frames):
    tr = read_trc(shared_data / GAIT / name)
    assert (tr.n_markers, tr.n_frames, tr.rate_hz) == (markers, frames, 60.0)
    assert tr.first_frame == 1
    assert "units mm -> m" in tr.conversions
    assert any("Y-up -> Z-up" in c for c in tr.conversions)
    assert tr.notes == []
    assert tr.gap_fraction == 0.0


def test_walk_times_and_axes(shared_data):
    tr = read_trc(shared_data / GAIT / "subject01_walk1.trc")
    assert tr.duration_s == pytest.approx(2.5)
    assert tr.extra["time_s"][-1] == pytest.approx(2.5, abs=0.02)
    # world Z is up: pelvis about 1 m above the heels
    pelvis = (tr.marker("R.ASIS") + tr.marker("L.ASIS")) / 2
    assert 0.75 < float(np.median(pelvis[:, 2] - tr.marker("R.Heel")[:, 2])) < 1.1
    # treadmill-style walk along OpenSim's X, which stays world X: the heel swings fore-aft
    # along X relative to the pelvis, hardly sideways
    heel = tr.marker("R.Heel") - pelvis
    assert np.ptp(heel[:, 0]) > 0.4 and np.ptp(heel[:, 1]) < 0.15
    # left is +Y in a right-handed Z-up X-forward frame
    assert np.all(tr.marker("L.ASIS")[:, 1] > tr.marker("R.ASIS")[:, 1])


def test_static_medial_markers(shared_data):
    tr = read_trc(shared_data / GAIT / "subject01_static.trc")
    for lab in ("R.Knee.Med", "L.Knee.Med", "R.Ankle.Med", "L.Ankle.Med"):
        assert lab in tr
    knee_width = np.linalg.norm(tr.marker("R.Knee.Lat") - tr.marker("R.Knee.Med"), axis=1)
    assert 0.06 < float(np.median(knee_width)) < 0.14


def test_round_trip_real_file(shared_data, tmp_path):
    tr = read_trc(shared_data / GAIT / "subject01_walk1.trc")
    tr.positions[5:9, 3] = np.nan  # a gap must survive the trip as blanks
    out = tmp_path / "copy.trc"
    write_trc(out, tr)
    back = read_trc(out)
    assert back.labels == tr.labels and back.rate_hz == tr.rate_hz
    assert np.array_equal(np.isnan(back.positions), np.isnan(tr.positions))
    assert np.nanmax(np.abs(back.positions - tr.positions)) < 1e-8
    assert "\t\t\t" in out.read_text().splitlines()[5 + 6]  # blank fields for the gap


def test_round_trip_in_metres(tmp_path):
    rng = np.random.default_rng(1)
    tr = MarkerTrial(["a", "b"], rng.normal(size=(7, 2, 3)), None, 250.0, first_frame=10)
    write_trc(tmp_path / "m.trc", tr, units="m")
    back = read_trc(tmp_path / "m.trc")
    assert not any("units" in c for c in back.conversions)
    assert back.first_frame == 10
    assert np.allclose(back.positions, tr.positions, atol=1e-6)


HEADER = ("PathFileType\t4\t(X/Y/Z)\tx.trc\n"
          "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n")


def _write(tmp_path, text, name="x.trc"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_malformed_but_readable_variants(tmp_path):
    # spaces in the header, names row with single tabs and one name short, no X1 row,
    # DataRate 0 (CameraRate used), NumFrames wrong, trailing empty columns, blanks and "nan"
    text = ("PathFileType 4 (X/Y/Z) x.trc\n"
            "DataRate CameraRate NumFrames NumMarkers Units\n"
            "0 100 5 3 m\n"
            "Frame#\tTime\tA\tB\n"
            "\n"
            "1\t0.00\t1\t2\t3\t4\t5\t6\t7\t8\t9\t\t\n"
            "2\t0.01\t1\t2\t3\t\t\t\t7\t8\t9\t\n"
            "3\t0.02\t1\t2\t3\tnan\tnan\tnan\t7\t8\n")
    tr = read_trc(_write(tmp_path, text))
    assert tr.labels == ["A", "B", "Marker3"]
    assert tr.rate_hz == 100.0 and tr.n_frames == 3
    assert not any("units" in c for c in tr.conversions)
    assert any("CameraRate" in n for n in tr.notes)
    assert any("NumFrames" in n for n in tr.notes)
    assert any("names row" in n for n in tr.notes)
    assert tr.valid.tolist() == [[True, True, True], [True, False, True], [True, False, False]]
    # Y-up file (x, y, z) = (1, 2, 3) m -> world (1, -3, 2)
    assert np.allclose(tr.positions[0, 0], [1.0, -3.0, 2.0])


def test_datarate_vs_camerarate_and_cm(tmp_path):
    text = HEADER + "50\t200\t2\t1\tcm\t50\t1\t2\nFrame#\tTime\tM\t\t\n\t\tX1\tY1\tZ1\n\n" \
        "1\t0\t100\t50\t0\n2\t0.02\t100\t50\t10\n"
    tr = read_trc(_write(tmp_path, text))
    assert tr.rate_hz == 50.0
    assert any("CameraRate 200" in n for n in tr.notes)
    assert "units cm -> m" in tr.conversions
    assert np.allclose(tr.positions[1, 0], [1.0, -0.1, 0.5])


@pytest.mark.parametrize("text, fault", [
    ("hello\n1\n2\n3\n4\n5\n", "not a TRC file"),
    (HEADER + "abc\t60\t1\t1\tmm\t60\t1\t1\nFrame#\tTime\tM\n\t\tX1\tY1\tZ1\n\n1\t0\t1\t2\t3\n",
     "DataRate"),
    (HEADER + "60\t60\t1\n", "TRC header is broken"),
    (HEADER + "60\t60\t1\t1\tfurlong\t60\t1\t1\nFrame#\tTime\tM\n\t\tX1\tY1\tZ1\n\n1\t0\t1\t2\t3\n",
     "Units"),
    (HEADER + "60\t60\t1\t1\tmm\t60\t1\t1\nMarkers\tA\n\t\tX1\tY1\tZ1\n\n1\t0\t1\t2\t3\n",
     "Frame# Time"),
    (HEADER + "60\t60\t1\t1\tmm\t60\t1\t1\nFrame#\tTime\tM\n\t\tX1\tY1\tZ1\n\n", "no data rows"),
    (HEADER + "60\t60\t1\t1\tmm\t60\t1\t1\nFrame#\tTime\tM\n\t\tX1\tY1\tZ1\n\n1\t0\t1\tx\t3\n",
     "not numeric"),
])
def test_broken_files_give_one_line_format_error(tmp_path, text, fault):
    with pytest.raises(FormatError) as exc:
        read_trc(_write(tmp_path, text, "broken.trc"))
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith("broken.trc: ")
    assert fault in msg
