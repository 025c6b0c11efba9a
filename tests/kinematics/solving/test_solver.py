"""Frame solver on the arm jig: quality codes, occlusion, NaN frames, gap filling, filters."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.testing import arm_jig
from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.kinematics.model import Quality
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver

GOOD, EST, MISS = Quality.GOOD, Quality.ESTIMATED, Quality.MISSING


@pytest.fixture(scope="module")
def jig():
    rng = np.random.default_rng(11)
    definition = SkeletonDefinition.from_layout_dict(arm_jig.ARM_LAYOUT, "arm_jig")
    gym_m, _ = arm_jig.forward(arm_jig.gym(rng, arm_jig.BASE_A, 800, 35.0))
    model = calibrate(definition, gym_m, rate_hz=100.0)
    # A smooth "performance" at 100 Hz, different from the gym.
    perf_m, perf_j = arm_jig.forward(arm_jig.gym(rng, arm_jig.BASE_A, 400, 25.0))
    return model, perf_m, perf_j


def test_clean_frames_are_exact_and_good(jig):
    model, markers, joints = jig
    res = FrameSolver(model).solve(markers)
    assert np.abs(res.joints - joints).max() < 1e-9
    assert (res.joint_quality == GOOD).all() and (res.limb_quality == GOOD).all()
    assert (res.limb_visible == 3).all()
    q = res.limb_rotation
    assert q.shape == (400, 4, 4)
    np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0)


def test_hidden_limb_marks_estimated_then_missing(jig):
    model, markers, joints = jig
    m = markers.copy()
    m[:, 7] = np.nan  # forearm: one of three markers hidden -> forearm can't be fitted
    res = FrameSolver(model, max_gap_s=0).solve(m)
    assert (res.limb_quality[:, 2] == MISS).all() and (res.limb_visible[:, 2] == 2).all()
    assert np.isnan(res.limb_rotation[:, 2]).all()
    # elbow seen from the upper arm, wrist from the hand: ESTIMATED, still exact
    assert (res.joint_quality[:, 1:] == EST).all()
    assert np.abs(res.joints - joints).max() < 1e-9
    m[:, 4] = np.nan   # and the upper arm
    m[:, 10] = np.nan  # and the hand
    res = FrameSolver(model, max_gap_s=0).solve(m)
    assert (res.joint_quality[:, 1:] == MISS).all() and np.isnan(res.joints[:, 1:]).all()
    assert (res.joint_quality[:, 0] == EST).all()  # shoulder from the clavicle


def test_nan_frames_do_not_crash_and_short_gaps_are_predicted(jig):
    model, markers, joints = jig
    m = markers.copy()
    m[100:105] = np.nan          # 50 ms hole: predicted
    m[200:240] = np.nan          # 400 ms hole: predicted for 0.1 s, then missing
    res = FrameSolver(model, rate_hz=100.0, max_gap_s=0.1).solve(m)
    assert (res.joint_quality[100:105] == EST).all()
    err = np.linalg.norm(res.joints[100:105] - joints[100:105], axis=-1)
    print("prediction error over a 50 ms gap (mm):", np.round(1000 * err.max(0), 2))
    assert err.max() < 0.02
    assert (res.joint_quality[200:210] == EST).all()
    assert (res.joint_quality[211:240] == MISS).all() and np.isnan(res.joints[211:240]).all()
    assert (res.joint_quality[240:] == GOOD).all()
    assert np.abs(res.joints[240:] - joints[240:]).max() < 1e-9
    # a lone NaN frame at the start, with nothing to predict from
    res = FrameSolver(model, rate_hz=100.0).solve(np.full((3, 12, 3), np.nan))
    assert (res.joint_quality == MISS).all() and np.isnan(res.joints).all()


def test_live_step_matches_batch(jig):
    model, markers, _ = jig
    m = markers.copy()
    m[50:53, :6] = np.nan
    kw = dict(rate_hz=100.0, max_gap_s=0.05, filter="one_euro")
    batch = FrameSolver(model, **kw).solve(m)
    live = FrameSolver(model, **kw)
    steps = [live.step(m[i]) for i in range(len(m))]
    np.testing.assert_allclose(np.stack([s.joints for s in steps]), batch.joints, atol=1e-12)
    np.testing.assert_array_equal(np.stack([s.joint_quality for s in steps]), batch.joint_quality)


@pytest.mark.parametrize("kind", ["one_euro", "constant_velocity"])
def test_filters_reduce_noise(jig, kind):
    model, markers, joints = jig
    rng = np.random.default_rng(0)
    # the arm held still for 2 s (at a non-base pose), with 2 mm marker noise
    markers = np.repeat(markers[150:151], 200, axis=0)
    joints = np.repeat(joints[150:151], 200, axis=0)
    noisy = markers + rng.normal(scale=0.002, size=markers.shape)
    raw = FrameSolver(model, rate_hz=100.0).solve(noisy).joints
    params = {"min_cutoff_hz": 3.0, "beta": 0.5} if kind == "one_euro" else {"alpha": 0.5, "beta": 0.1}
    filt = FrameSolver(model, rate_hz=100.0, filter=kind, filter_params=params).solve(noisy).joints
    e_raw = np.sqrt(np.mean((raw[20:] - joints[20:]) ** 2))
    e_filt = np.sqrt(np.mean((filt[20:] - joints[20:]) ** 2))
    print(f"{kind}: rms error raw {1000 * e_raw:.2f} mm, filtered {1000 * e_filt:.2f} mm")
    assert e_filt < 0.7 * e_raw


def test_bone_lengths_are_enforced(jig):
    model, markers, _ = jig
    rng = np.random.default_rng(1)
    noisy = markers + rng.normal(scale=0.003, size=markers.shape)
    res = FrameSolver(model).solve(noisy)
    d = np.linalg.norm(res.joints[:, 1:] - res.joints[:, :2], axis=-1)
    np.testing.assert_allclose(d, np.broadcast_to(model.bone_length[1:], d.shape), atol=1e-9)
    free = FrameSolver(model, enforce_lengths=False).solve(noisy)
    d_free = np.linalg.norm(free.joints[:, 1:] - free.joints[:, :2], axis=-1)
    assert d_free.std(0).min() > 1e-4


def test_swapped_marker_is_flagged_and_down_weighted(jig):
    model, markers, joints = jig
    m = markers.copy()
    m[:, [5, 6]] = m[:, [6, 5]]  # an upper-arm and a forearm label swapped
    res = FrameSolver(model, max_gap_s=0).solve(m)
    assert (res.limb_quality[:, 1:3] == EST).all()
    assert (res.joint_quality[:, 1] == GOOD).all()  # both limbs still fitted, just poorly
