"""BVH and TRC files a careless or hostile user gives ``bag convert`` (issue 30 item 11): each is
refused in one line with exit 2, fast and within bounded memory, or read right with a note."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lab_fixtures import PERSON_LABELS, bvh_with_root_offset, person_frames, write_points_c3d
from mocapgraph.bag.reader import BagReader
from mocapgraph.formats import read_c3d, write_trc
from mocapgraph.testing.c3d_fuzz import convert as measured_convert


def convert(src: Path, out: Path) -> subprocess.CompletedProcess:
    """``mocapgraph bag convert SRC -o OUT`` as the user runs it."""
    return subprocess.run([sys.executable, "-m", "mocapgraph", "bag", "convert", str(src), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)


def refused(r: subprocess.CompletedProcess, *fragments: str) -> None:
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    for f in fragments:
        assert f in lines[0], lines[0]


def edit_bvh(tmp_path: Path, old: str, new: str, name: str) -> Path:
    src = bvh_with_root_offset(tmp_path / "ok.bvh")
    text = src.read_text()
    assert old in text
    p = tmp_path / name
    p.write_text(text.replace(old, new, 1))
    return p


@pytest.mark.parametrize("frame_time", ["nan", "inf", "-inf", "1e300"])
def test_bvh_frame_time_not_a_number_of_seconds_is_refused(tmp_path: Path, frame_time: str) -> None:
    p = edit_bvh(tmp_path, "Frame Time: 0.0333333", f"Frame Time: {frame_time}", "t.bvh")
    r = convert(p, tmp_path / "t.mcap")
    refused(r, "t.bvh", "Frame Time", "is not a positive number of seconds")
    assert not (tmp_path / "t.mcap").exists()


def test_bvh_infinite_offset_or_channel_value_is_refused(tmp_path: Path) -> None:
    p = edit_bvh(tmp_path, "OFFSET 0 -45 0", "OFFSET 0 -inf 0", "off.bvh")
    refused(convert(p, tmp_path / "a.mcap"), "off.bvh", "OFFSET", "not three finite numbers")
    src = bvh_with_root_offset(tmp_path / "ok.bvh").read_text().splitlines()
    src[-1] = src[-1].replace("0 90", "0 inf", 1)
    (tmp_path / "val.bvh").write_text("\n".join(src) + "\n")
    refused(convert(tmp_path / "val.bvh", tmp_path / "b.mcap"), "val.bvh", "1 non-finite values",
            "frame 3")


def test_bvh_duplicate_joint_names_are_refused_naming_both(tmp_path: Path) -> None:
    p = edit_bvh(tmp_path, "JOINT RightLeg", "JOINT LeftLeg", "dup.bvh")
    refused(convert(p, tmp_path / "d.mcap"), "dup.bvh", "'LeftLeg' is used twice")


def test_a_million_joint_bvh_is_refused_fast(tmp_path: Path) -> None:
    joints = "".join(f"JOINT j{k}\n{{\nOFFSET 0 1 0\nCHANNELS 0\n}}\n" for k in range(10**6))
    p = tmp_path / "huge.bvh"
    p.write_text("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n" + joints
                 + "}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0\n")
    assert p.stat().st_size > 30e6
    run = measured_convert(p, tmp_path / "h.mcap", timeout_s=120)
    refused(subprocess.CompletedProcess([], run.code, "", run.stderr), "huge.bvh", "more than any skeleton",
            "4096 joints")
    assert run.seconds < 30 and run.peak_rss_mb < 400, run  # was: past 120 s at 2.2 GB
    # a smaller one that passes the text bound still stops at the joint bound
    few = "".join(f"JOINT j{k} {{ OFFSET 0 1 0 CHANNELS 0 }}\n" for k in range(5000))
    (tmp_path / "many.bvh").write_text("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Zrotation Xrotation "
                                       "Yrotation\n" + few + "}\nMOTION\nFrames: 1\nFrame Time: 0.01\n0 0 0\n")
    refused(convert(tmp_path / "many.bvh", tmp_path / "m.mcap"), "many.bvh", "more than 4096 joints")


def test_one_over_long_trc_row_adds_no_phantom_marker(tmp_path: Path) -> None:
    truth = person_frames(30)
    trial = read_c3d(write_points_c3d(tmp_path / "p.c3d", PERSON_LABELS, truth, y_screen="+Z"))
    trc = tmp_path / "long.trc"
    write_trc(trc, trial)
    lines = trc.read_text().splitlines()
    row = 6 + 12  # the 13th data row
    lines[row] += "\t1.0\t2.0\t3.0\t4.0\t5.0\t6.0"
    trc.write_text("\n".join(lines) + "\n")
    r = convert(trc, tmp_path / "long.mcap")
    assert r.returncode == 0, r.stderr
    assert f"1 data row(s) hold more fields than the 4 markers (first: line {row + 1}" in r.stdout
    with BagReader(tmp_path / "long.mcap") as b:
        (layout,) = [m for _, m in b.decoded("marker_layout")]
        frames = [m for _, m in b.decoded("markers")]
    assert layout.labels == list(PERSON_LABELS)
    assert all(f.positions.shape == (4, 3) for f in frames)
    np.testing.assert_allclose(np.stack([f.positions for f in frames]), truth, atol=1e-6)

