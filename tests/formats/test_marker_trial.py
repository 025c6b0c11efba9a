"""MarkerTrial helpers and the by-extension dispatch."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats import FormatError, MarkerTrial, read_markers, write_markers


def _trial():
    pos = np.arange(4 * 3 * 3, dtype=float).reshape(4, 3, 3) / 100
    pos[2, 1] = np.nan
    return MarkerTrial(["LASI", "RASI", "C7"], pos, None, 100.0, first_frame=11, source="t")


def test_sizes_time_and_gaps():
    tr = _trial()
    assert (tr.n_frames, tr.n_markers) == (4, 3)
    assert np.allclose(tr.times_s, [0, 0.01, 0.02, 0.03])
    assert tr.timestamps_ns.tolist() == [0, 10_000_000, 20_000_000, 30_000_000]
    assert tr.gap_fraction == pytest.approx(1 / 12)
    assert np.isnan(tr.residuals[2, 1]) and tr.residuals[0, 0] == 0.0


def test_select_case_insensitive_and_missing():
    tr = _trial()
    sub = tr.select(["c7", "lasi"])
    assert sub.labels == ["C7", "LASI"]
    assert np.array_equal(sub.positions[:, 0], tr.positions[:, 2])
    with pytest.raises(KeyError):
        tr.select(["LKNE"])
    padded = tr.select(["LKNE", "RASI"], missing="nan")
    assert np.isnan(padded.positions[:, 0]).all() and padded.labels[0] == "LKNE"
    assert tr.select(["LKNE", "RASI"], missing="drop").labels == ["RASI"]
    assert "rasi" in tr and "LKNE" not in tr


def test_frames_slice_keeps_frame_numbers():
    part = _trial().frames(1, 3)
    assert part.n_frames == 2 and part.first_frame == 12


def test_shape_checks():
    with pytest.raises(ValueError):
        MarkerTrial(["a"], np.zeros((2, 2, 3)), None, 100.0)
    with pytest.raises(ValueError):
        MarkerTrial(["a"], np.zeros((2, 1, 3)), None, 0.0)


@pytest.mark.parametrize("ext", [".c3d", ".trc"])
def test_dispatch_round_trip(tmp_path, ext):
    tr = _trial()
    write_markers(tmp_path / f"x{ext}", tr)
    back = read_markers(tmp_path / f"x{ext}")
    assert back.labels == tr.labels and back.n_frames == 4 and back.first_frame == 11
    assert np.array_equal(back.valid, tr.valid)
    assert np.nanmax(np.abs(back.positions - tr.positions)) < 1e-6


def test_dispatch_unknown_extension(tmp_path):
    with pytest.raises(FormatError, match=r"^x\.csv: unknown marker file type"):
        read_markers(tmp_path / "x.csv")
