"""C3D parameter layouts ezc3d's writer never produces (issue 30 item 12), in files written byte
by byte here: an Optotrak export whose header says frames 1..1149 while its int16 POINT:FRAMES
(29) matches the 29 frames of its data block (54 points, float data), with its parameters
stored before their group's record. Read whole by the reader and by ``bag convert``."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from c3d_bytes import write_float_c3d
from mocapgraph.bag.reader import BagReader
from mocapgraph.formats import FormatError, read_c3d

LABELS = [f"OPTO{k:02d}" for k in range(54)]


def optotrak_points(T: int = 29) -> np.ndarray:
    """[T, 54, 3] mm: 54 IREDs on a body moving 1 mm per frame along X, a few samples missing."""
    rng = np.random.default_rng(12)
    pts = rng.uniform(-800.0, 800.0, (1, 54, 3)) + np.arange(T)[:, None, None] * np.array([1.0, 0, 0])
    pts[3, 7] = np.nan
    pts[20, 40] = np.nan
    return pts


@pytest.mark.parametrize("layout", ["params_first", "groups_first", "array_scalars"])
def test_optotrak_header_1149_point_frames_29_reads_29_frames(tmp_path: Path, layout: str) -> None:
    truth = optotrak_points()
    path = write_float_c3d(tmp_path / "optotrak.c3d", LABELS, truth, header_last=1149, point_frames=29,
                           layout=layout)
    tr = read_c3d(path, up_axis="z")
    assert tr.n_frames == 29 and tr.labels == LABELS and tr.first_frame == 1
    np.testing.assert_allclose(tr.positions * 1000.0, truth, atol=1e-3)  # float32 in the file
    assert np.isnan(tr.positions[3, 7]).all() and np.isnan(tr.positions[20, 40]).all()
    assert any("disagree with POINT:FRAMES 29; used POINT:FRAMES" in n for n in tr.notes)


def test_optotrak_file_converts_whole_through_the_cli(tmp_path: Path) -> None:
    truth = optotrak_points()
    path = write_float_c3d(tmp_path / "optotrak.c3d", LABELS, truth, header_last=1149, point_frames=29,
                           layout="params_first")
    out = tmp_path / "optotrak.mcap"
    proc = subprocess.run([sys.executable, "-m", "mocapgraph", "bag", "convert", str(path), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    with BagReader(out) as r:
        frames = [m.decode()[1] for m in r.messages(topics=["markers"])]
    assert len(frames) == 29
    np.testing.assert_allclose(frames[-1].positions[0] * 1000.0, truth[-1, 0], atol=1e-3)


def test_params_first_file_cut_inside_its_data_is_still_refused(tmp_path: Path) -> None:
    truth = optotrak_points()
    path = write_float_c3d(tmp_path / "cut.c3d", LABELS, truth, header_last=1149, point_frames=29,
                           layout="params_first")
    raw = path.read_bytes()
    path.write_bytes(raw[:3 * 512 + 10 * 54 * 16])  # 10 of 29 frames
    with pytest.raises(FormatError) as e:
        read_c3d(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith("cut.c3d: ")
    assert "data block holds 10 frames, POINT:FRAMES promises 29 and the header 1149" in msg
