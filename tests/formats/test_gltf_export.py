"""glTF/GLB export: `mocapgraph retarget ... -o out.glb|.gltf` passes the Khronos validator with 0
errors, and the file read back by pygltflib (our own node-tree arithmetic over its accessors) puts
every joint where the same run's `character_pose` (the .mcap output) says, within 1e-4 m, at the
source's frame times; nothing is written half."""
from __future__ import annotations

import contextlib
import io
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gltf_support import animated_world_positions, khronos_report
from mocapgraph.bag.reader import BagReader
from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.gltf_export import GltfExportError, write_gltf

# glTF (x left, y up, z forward) -> ours (x forward, y left, z up), written out here
OURS_FROM_GLTF = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _retarget(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    from mocapgraph.cli import main
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(["retarget", *args])
            except SystemExit as exc:
                code = int(exc.code or 0)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def _errors(report: dict) -> list[str]:
    return [f"{m['code']}: {m['message']} ({m.get('pointer')})" for m in report["issues"]["messages"]
            if m["severity"] == 0]


@pytest.mark.slow
def test_retargeted_cmu_on_mixamo_as_glb_and_gltf(tmp_path, shared_data):
    src = str(shared_data / "bvh/cmu/131_01.bvh")
    r = _retarget(src, "--character", "mixamo", "-o", "out.mcap", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    with BagReader(tmp_path / "out.mcap") as bag:
        poses = [m for _, m in bag.decoded("character_pose")]
    truth = np.stack([p.joint_positions for p in poses])
    mix = load_character("mixamo")
    frames = [0, 1, 250, 500, 777, len(poses) - 1]
    for name in ("out.glb", "out.gltf"):
        r = _retarget(src, "--character", "mixamo", "-o", name, cwd=tmp_path)
        assert r.returncode == 0, r.stderr
        assert "994 keys at the source's frame times" in r.stdout
        report = khronos_report(tmp_path / name)
        assert report["issues"]["numErrors"] == 0, _errors(report)
        names, times, world = animated_world_positions(tmp_path / name, frames)
        assert names == list(mix.joint_names) and len(times) == len(poses) == 994
        np.testing.assert_allclose(np.diff(times), 1 / 120, atol=1e-5)
        ours = world @ OURS_FROM_GLTF.T
        worst = float(np.abs(ours - truth[frames]).max())
        print(f"\n{name}: {(tmp_path / name).stat().st_size / 1e6:.2f} MB, validator: "
              f"{report['issues']['numErrors']} errors, {report['issues']['numWarnings']} warnings; "
              f"joints vs character_pose over {len(frames)} frames: max {worst * 1000:.4f} mm")
        assert worst < 1e-4
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".part")]


def _random_take(ch, frames: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    q = Rotation.from_rotvec(rng.normal(scale=0.6, size=(frames * ch.n_joints, 3))).as_quat()[:, [3, 0, 1, 2]]
    root = rng.normal(scale=0.5, size=(frames, 3)) + [0, 0, 1]
    return q.reshape(frames, ch.n_joints, 4), root


@pytest.mark.parametrize("name", ["standard_20", "cmu"])
def test_a_shipped_character_with_a_random_take(tmp_path, name):
    """No capture needed: every joint turned at random each frame (sign flips and all), any rig."""
    ch = load_character(name)
    q, root = _random_take(ch, 40)
    t = np.cumsum(np.r_[0.0, np.full(39, 1 / 30)]) + 5.0     # keys start at 0 s in the file
    write_gltf(tmp_path / "a.glb", ch, q, root, t)
    report = khronos_report(tmp_path / "a.glb")
    assert report["issues"]["numErrors"] == 0, _errors(report)
    names, times, world = animated_world_positions(tmp_path / "a.glb", list(range(40)))
    assert names == list(ch.joint_names) and times[0] == 0 and abs(times[-1] - 39 / 30) < 1e-6
    truth, _ = ch.forward_kinematics(q, root)
    assert float(np.abs(world @ OURS_FROM_GLTF.T - truth).max()) < 1e-5


def test_nothing_is_written_half(tmp_path):
    ch = load_character("standard_20")
    q, root = _random_take(ch, 5)
    target = tmp_path / "keep.glb"
    target.write_bytes(b"the old file")
    q[3, 4] = np.nan
    with pytest.raises(GltfExportError, match="non-finite"):
        write_gltf(target, ch, q, root, np.arange(5) / 30)
    with pytest.raises(GltfExportError, match="strictly increasing"):
        write_gltf(target, ch, _random_take(ch, 5)[0], root, np.array([0, 1, 1, 2, 3]) / 30)
    assert target.read_bytes() == b"the old file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.glb"]
    # the rename fails (a folder of that name): an OSError, the folder as it was, no temporary file
    (tmp_path / "dir.glb").mkdir()
    with pytest.raises(OSError):
        write_gltf(tmp_path / "dir.glb", ch, _random_take(ch, 2)[0], root[:2], [0, 0.1])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dir.glb", "keep.glb"]
    assert list((tmp_path / "dir.glb").iterdir()) == []


def test_key_times_from_the_source_or_from_the_rate():
    from mocapgraph.cli.gltf_out import key_times
    t, how = key_times(np.array([10.0, 10.01, 10.02]), 100.0)
    assert np.allclose(t, [0, 0.01, 0.02]) and how == "the source's frame times"
    t, how = key_times(np.array([10.0, 10.0, 10.02, 10.01]), 50.0)      # repeats and goes back (a Kinect log)
    assert np.allclose(t, [0, 0.02, 0.04, 0.06]) and "50 Hz" in how
