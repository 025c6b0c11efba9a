"""The streaming calibration capture on capture stamps: base pose, gym sampling, timeout."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.kinematics.calibration.capture_steps import FOUND, SEARCHING, TIMED_OUT, CaptureSession, GymSampler

NS = 1_000_000_000


def test_base_pose_then_gym_at_the_asked_rate_from_its_own_start() -> None:
    cap = CaptureSession(timeout_s=1.0, gym_seconds=1.0, gym_rate_hz=60.0)
    x = np.zeros((3, 3))
    ok = np.array([True, False, True])
    t0 = 5 * NS  # stamps need not start at 0
    assert cap.search(x, ok, t0, 10) == SEARCHING
    assert cap.search(x + 1, np.ones(3, bool), t0 + NS // 120, 11) == FOUND
    assert cap.base_frame == 11 and cap.base[0, 0] == 1
    cap.start_gym(1.0, 60.0)
    stamps = t0 + NS + np.arange(240) * NS // 120  # 2 s at 120 Hz, the gym starts at the first
    done = [cap.sample(np.full((3, 3), k, float), int(ns)) for k, ns in enumerate(stamps)]
    assert done.index(True) == 120                  # 1 s after the gym's first frame
    kept = [int(f[0, 0]) for f in cap.gym]
    assert kept == list(range(0, 120, 2))           # 60 frames/s of a 120 Hz stream
    frames = cap.frames()
    assert frames.shape == (61, 3, 3) and frames[0, 0, 0] == 1
    assert cap.gym_data(120.0) == {"frames": 60, "seconds": 1.0, "rate_hz": 60.0}
    assert cap.frames_used == 2 + 240          # every frame offered counts


def test_search_times_out_and_says_which_markers_never_showed() -> None:
    cap = CaptureSession(timeout_s=0.5, gym_seconds=1.0, gym_rate_hz=0.0)
    ok = np.array([True, False, False])
    results = [cap.search(np.zeros((3, 3)), ok if k % 2 else ok[[1, 0, 2]], k * NS // 10, k) for k in range(6)]
    assert results[-2:] == [SEARCHING, TIMED_OUT] and cap.base is None
    assert cap.finder.never_seen.tolist() == [False, False, True]


def test_gym_args_are_checked() -> None:
    assert GymSampler.checked("2", 0) == (2.0, 0.0)
    for bad in ((0, 60), (1, -1), ("x", 60), (None, 60)):
        with pytest.raises(ValueError, match="seconds must be > 0"):
            GymSampler.checked(*bad)
