"""`mocapgraph retarget VIDEO` and `mocapgraph bag convert VIDEO` in batch: one camera's markerless
skeleton onto standard_20 (the shipped Kinect v2 mapping serves: the video skeleton has Kinect v2
joints) and Mixamo (mapping derived automatically), and into a bag read back."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("mediapipe")

from graph_helpers import run_concurrently  # noqa: E402
from mocapgraph.bag.reader import BagReader  # noqa: E402

pytestmark = pytest.mark.slow          # the commands as programs, the estimator on 100 frames each


def _cli(*args, cwd) -> subprocess.CompletedProcess:
    return subprocess.run(_command(*args), capture_output=True, text=True, cwd=cwd, timeout=300)


def _command(*args) -> list[str]:
    return [sys.executable, "-m", "mocapgraph", *map(str, args)]


def test_bag_convert_then_retarget_a_video(tmp_path, shared_data) -> None:
    video = shared_data / "video" / "pose2sim_demo" / "cam04.mp4"
    # the three commands on the video are independent: each estimator runs on one core, so they
    # run at once (graph_helpers.run_concurrently) instead of queueing
    to_bvh, to_bag, nothing = run_concurrently([
        _command("retarget", video, "--character", "mixamo", "--mapping-out", "m.yaml", "-o", "v.bvh"),
        _command("bag", "convert", video, "-o", "v.mcap"),
        _command("retarget", tmp_path / "nothing.mp4", "-o", "x.bvh")], timeout=300, cwd=tmp_path)
    r = to_bvh
    assert r.returncode == 0, r.stderr
    assert "cam04.mp4 onto mixamo: 100 frames" in r.stdout
    assert "source: kinect_v2" in (tmp_path / "m.yaml").read_text()           # derived automatically
    r = to_bag
    assert r.returncode == 0, r.stderr
    with BagReader(tmp_path / "v.mcap") as bag:
        assert sum(1 for m in bag.messages(["skeleton_pose"])) == 100
    # the bag (no estimator again) onto standard_20 with the shipped Kinect v2 mapping
    r = _cli("retarget", "v.mcap", "--character", "standard_20", "--mapping", "kinect_v2_standard_20", "-o", "v.csv",
             cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "v.mcap onto standard_20: 100 frames, 20 joints" in r.stdout
    rows = np.loadtxt(tmp_path / "v.csv", delimiter=",", skiprows=1)
    assert rows.shape[0] == 100 and np.isfinite(rows[:, 2:]).all()
    r = nothing
    assert r.returncode != 0 and "Traceback" not in r.stderr and "nothing.mp4" in r.stderr
