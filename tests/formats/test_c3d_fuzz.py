"""Damaged copies of the shared C3D files through ``mocapgraph bag convert`` (issue 30 item 3): each
either converts or fails in one line, never with a traceback or a crash, within 10x the file's
size plus a fixed 150 MB (the interpreter with numpy, scipy, ezc3d and mcap takes 75-100 MB).

Here: the byte changes that made ezc3d allocate 4 GB, crash (SIGSEGV), loop for minutes, or the
reader raise, plus one seeded structural change per file. ``benchmarks/c3d_fuzz.py`` runs 50
seeded copies of each file and prints the figures.
"""
from __future__ import annotations

from pathlib import Path

import pytest

from mocapgraph.testing.c3d_fuzz import convert, mutate, structural_offsets

MARGIN_MB = 150.0
FILES = ["pycgm/Static_trial.c3d", "pycgm/Movement_trial.c3d", "ezc3d-testFiles/Qualisys.c3d",
         "ezc3d-testFiles/BTS.c3d", "ezc3d-testFiles/FP_Type1.c3d", "btkdata/golfswing.c3d",
         "btkdata/mocap36.c3d"]

# (file, parameter, which byte of its record, new value, what it did before the fix)
KNOWN = [
    ("ezc3d-testFiles/BTS.c3d", "FORCE_PLATFORM:CORNERS", "dim1", 0, "ezc3d allocated 4.1 GB, 8-21 s"),
    ("ezc3d-testFiles/FP_Type1.c3d", "FORCE_PLATFORM:CORNERS", "type", 255, "ezc3d allocated 4.1 GB, 12 s"),
    ("ezc3d-testFiles/FP_Type1.c3d", "FORCE_PLATFORM:CORNERS", "ndim", 127, "ezc3d looped for minutes"),
    ("ezc3d-testFiles/FP_Type1.c3d", "ANALOG:DESCRIPTIONS", "gid", 128, "ezc3d crashed (SIGSEGV)"),
    ("ezc3d-testFiles/FP_Type1.c3d", "ANALOG:OFFSET", "name2", 0, "ezc3d crashed (SIGSEGV)"),
    ("ezc3d-testFiles/BTS.c3d", "POINT:RATE", "value3", 128, "traceback: rate_hz must be positive"),
    ("ezc3d-testFiles/BTS.c3d", "POINT:USED", "value1", 127, "ezc3d read 32534 points of garbage, 8 s"),
]


def _spot(raw: bytes, param: str, which: str) -> int:
    spots = structural_offsets(raw)[param]  # [name length, gid, offset lo, hi, type, ndim, dims..., value...]
    if which.startswith("name"):
        return spots[1] + 1 + int(which[4:])
    nd = raw[spots[5]]
    return {"gid": spots[1], "type": spots[4], "ndim": spots[5]}.get(which) or (
        spots[6 + int(which[3:])] if which.startswith("dim") else spots[6 + nd + int(which[5:])])


def check(run, size: int, what: str) -> None:
    assert run.code in (0, 2), f"{what}: exit {run.code}: {run.stderr[-400:]}"
    assert not run.traceback, f"{what}: {run.stderr[-800:]}"
    if run.code == 2:
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("mocapgraph: "), f"{what}: {run.stderr!r}"
    bound = 10 * size / 2**20 + MARGIN_MB
    assert run.peak_rss_mb < bound, f"{what}: peak {run.peak_rss_mb:.0f} MB > {bound:.0f} MB"


@pytest.mark.parametrize("name,param,which,value,before", KNOWN, ids=[f"{k[1]}-{k[2]}" for k in KNOWN])
def test_known_bad_bytes_give_one_line_within_the_memory_bound(shared_data, tmp_path: Path, name, param,
                                                                which, value, before) -> None:
    raw = (shared_data / "c3d" / name).read_bytes()
    at = _spot(raw, param, which)
    assert raw[at] != value
    bad = bytearray(raw)
    bad[at] = value
    src = tmp_path / Path(name).name
    src.write_bytes(bytes(bad))
    run = convert(src, tmp_path / "out.mcap", timeout_s=120)
    check(run, len(raw), f"{name} {param} {which}={value} (was: {before})")
    assert run.seconds < 60


@pytest.mark.parametrize("name", FILES)
def test_seeded_structural_damage_gives_one_line_within_the_memory_bound(shared_data, tmp_path: Path,
                                                                          name: str) -> None:
    raw = (shared_data / "c3d" / name).read_bytes()
    for seed in (0,):
        data, what = mutate(raw, seed)
        src = tmp_path / Path(name).name
        src.write_bytes(data)
        run = convert(src, tmp_path / f"out{seed}.mcap", timeout_s=120)
        check(run, len(raw), f"{name} seed {seed}: {what}")
