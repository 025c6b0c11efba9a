"""`mocapgraph retarget` on files: BVH export read back by an independent reader (bvhio), bags, CSV,
and bad input as a new user would try it."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.bag.reader import BagReader
from mocapgraph.formats.character_file import load_character

pytestmark = pytest.mark.slow  # the retarget command as processes, on real captures


def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """The `mocapgraph retarget` command line, run in this process (its entry point, its output)."""
    import contextlib
    import io
    import os

    from mocapgraph.cli import main
    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(["retarget", *args])
            except SystemExit as exc:      # argparse errors
                code = int(exc.code or 0)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(args, code, out.getvalue(), err.getvalue())


def test_the_command_runs_as_a_program(tmp_path, shared_data):
    r = subprocess.run([sys.executable, "-m", "mocapgraph", "retarget", str(shared_data / "kinect2/Ges05_demopoint.csv"),
                        "-o", "k.mcap"], capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Ges05_demopoint.csv onto standard_20: 190 frames" in r.stdout and (tmp_path / "k.mcap").exists()


def test_cmu_onto_mixamo_bvh_reads_back_in_bvhio(tmp_path, shared_data):
    bvhio = pytest.importorskip("bvhio")
    src = shared_data / "bvh/cmu/131_01.bvh"
    r = _run(str(src), "--character", "mixamo", "-o", "out.bvh", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    r2 = _run(str(src), "--character", "mixamo", "-o", "out.mcap", cwd=tmp_path)
    assert r2.returncode == 0, r2.stderr
    print("\n" + r.stdout.strip())
    with BagReader(tmp_path / "out.mcap") as bag:
        poses = [m for _, m in bag.decoded("character_pose")]
        info = [m for _, m in bag.decoded("character_info")][-1]
    mix = load_character("mixamo")
    assert list(info.joint_names) == list(mix.joint_names)
    container = bvhio.readAsBvh(str(tmp_path / "out.bvh"))
    assert container.FrameCount == len(poses) == 994
    assert abs(container.FrameTime - 1 / 120) < 1e-6
    root = bvhio.readAsHierarchy(str(tmp_path / "out.bvh"))
    joints = {j.Name: j for j, _, _ in root.layout()}
    real = [n for j, n in enumerate(mix.joint_names) if not mix.end_sites[j]]
    assert set(joints) == set(real)                              # every joint, end sites as End Site
    assert container.Root.Channels[:3] == ["Xposition", "Yposition", "Zposition"]
    # offsets as the character's (cm, Y up): spot-check a forearm
    fore = joints["LeftForeArm"]
    off = np.array([fore.Position.x, fore.Position.y, fore.Position.z]) if hasattr(fore, "Position") else None
    worst = 0.0
    for f in (0, 250, 500, 993):
        root.loadPose(f)
        for name, j in joints.items():
            p = j.PositionWorld
            world = np.array([p.z, p.x, p.y]) * 0.01            # BVH (x left, y up, z forward) -> ours
            worst = max(worst, float(np.abs(world - poses[f].joint_positions[mix.index(name)]).max()))
    print(f"bvhio's joint positions vs ours over 4 frames x {len(joints)} joints: max {1000 * worst:.4f} mm")
    assert worst < 1e-4
    assert off is None or np.linalg.norm(off) > 1.0


def test_kinect_csv_to_csv_and_bag(tmp_path, shared_data):
    src = shared_data / "kinect2/Ges04_comehere.csv"
    r = _run(str(src), "--mapping", "kinect_v2_standard_20", "--height", "1.6", "-o", "k.csv", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = (tmp_path / "k.csv").read_text().splitlines()
    head = lines[0].split(",")
    assert head[:2] == ["frame", "time_s"] and "ElbowLeft_qw" in head and "HandRight_quality" in head
    assert len(lines) - 1 == 172
    row = np.array([float(x) for x in lines[50].split(",")])
    q = row[2:].reshape(20, 8)[:, 3:7]
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-5)


def test_mapping_command_writes_an_editable_file(tmp_path, shared_data):
    r = _run("mapping", str(shared_data / "bvh/cmu/131_01.bvh"), "--character", "mixamo", "-o", "m.yaml", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    text = (tmp_path / "m.yaml").read_text()
    assert "LeftArm: {rotation: LeftShoulder" in text and "LeftShoulder: {mode: aim" in text
    # the written file drives the batch command as it is
    r = _run(str(shared_data / "bvh/cmu/131_01.bvh"), "--character", "mixamo", "--mapping", "m.yaml", "-o", "o.csv",
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("edit,needle", [
    (("LeftArm: {rotation: LeftShoulder", "LeftArmm: {rotation: LeftShoulder"),
     "joints.LeftArmm: character 'mixamo' has no joint 'LeftArmm' (did you mean LeftArm"),
    (("LeftArm: {rotation: LeftShoulder, position: LeftShoulder, R: [", "LeftArm: {rotation: LeftShoulder, "
      "position: LeftShoulder, R: [2, "), "joints.LeftArm.R: "),
    (("LeftForeArm: {rotation: LeftElbow", "LeftForeArm: {rotation: LeftElbw"),
     "has no rotation 'LeftElbw' (did you mean LeftElbow"),
])
def test_bad_mapping_files_are_one_line_errors(tmp_path, shared_data, edit, needle):
    from mocapgraph.formats.mapping_file import write_mapping
    from mocapgraph.retarget.mapping import derive_mapping
    from retarget_cli_support import cmu_source
    bvh = str(shared_data / "bvh/cmu/131_01.bvh")
    write_mapping(derive_mapping(load_character("mixamo"), cmu_source(bvh)), tmp_path / "m.yaml")
    text = (tmp_path / "m.yaml").read_text()
    assert edit[0] in text
    (tmp_path / "bad.yaml").write_text(text.replace(edit[0], edit[1], 1))
    r = _run(bvh, "--character", "mixamo", "--mapping", "bad.yaml", "-o", "o.bvh", cwd=tmp_path)
    assert r.returncode == 2
    err = r.stderr.strip()
    assert "\n" not in err and "Traceback" not in err and needle in err, err
    line = next(i + 1 for i, ln in enumerate((tmp_path / "bad.yaml").read_text().splitlines()) if edit[1][:12] in ln)
    assert f"bad.yaml:{line}:" in err, err
    assert not (tmp_path / "o.bvh").exists()


def test_bad_inputs_a_new_user_would_try(tmp_path, shared_data):
    bvh = str(shared_data / "bvh/cmu/131_01.bvh")
    (tmp_path / "cycle.yaml").write_text("name: c\njoints:\n  - {name: a, offset: [0, 0, 1]}\n"
                                         "  - {name: b, parent: c, offset: [0, 0, 1]}\n  - {name: c, parent: b, offset: [0, 0, 1]}\n")
    cases = [
        ((bvh, "--character", "cycle.yaml", "-o", "o.bvh"), "cycle.yaml:4: joints[1] (b).parent: parent 'c' is defined later"),
        ((bvh, "--character", "standard_20", "--mapping", "kinect_v2_standard_20", "-o", "o.bvh"),
         "has no rotation 'SpineBase'"),             # a Kinect mapping on a BVH skeleton: the wrong source
        ((str(shared_data / "kinect2/Ges01_wavehand.csv"), "--mapping", "kinect_v1_standard_20", "-o", "o.bvh"),
         "has no rotation 'HipCenter'"),             # a v1 mapping (20 joints) on a v2 stream
        ((bvh, "-o", "o.fbx"), "unknown output type '.fbx'"),
        (("nope.bvh", "-o", "o.bvh"), "nope.bvh: no such file"),
        ((str(shared_data / "c3d/pycgm/Movement_trial.c3d"), "-o", "o.bvh"), "markers need an actor model"),
        ((bvh, "--character", "mixamoo", "-o", "o.bvh"), "no such character file or shipped character"),
    ]
    for args, needle in cases:
        r = _run(*args, cwd=tmp_path)
        err = r.stderr.strip()
        assert r.returncode == 2 and needle in err and "\n" not in err and "Traceback" not in err, (args, err)
