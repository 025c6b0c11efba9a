"""Full body: calibrate on the synthetic actor's gym, solve its performance, compare with truth."""
from __future__ import annotations

import copy
import functools

import numpy as np
import pytest

from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.kinematics.model import Quality
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor


@functools.lru_cache(maxsize=2)
def _calibrated(options: CaptureOptions, seed: int):
    """(capture, model) calibrated on the base-pose hold + gym: built once per options (four tests
    calibrate on the same 1 mm capture, hiding markers only in the performance they solve)."""
    cap = SyntheticActor("kiip_full_body", options=options, seed=seed).capture()
    calib = slice(0, cap.phases["gym"][1])  # base-pose hold + gym
    return cap, calibrate(cap.skeleton, cap.markers[calib], rate_hz=cap.rate, source="synthetic")


def _run(options: CaptureOptions, hide: list[str] | None = None, seed: int = 0):
    cap, model = copy.deepcopy(_calibrated(options, seed))
    perf = cap.phase_slice("performance")
    markers = cap.markers[perf].copy()
    if hide:
        markers[:, [cap.skeleton.marker_labels.index(m) for m in hide]] = np.nan
    res = FrameSolver(model, rate_hz=cap.rate).solve(markers)
    err = np.linalg.norm(res.joints - cap.joint_centres[perf], axis=-1)
    return cap, model, res, err


def _report(name: str, err: np.ndarray, names) -> None:
    per = 1000 * np.nanmean(err, axis=0)
    worst = np.argsort(per)[::-1][:4]
    print(f"\n{name}: mean {1000 * np.nanmean(err):.2f} mm, 95th pct {1000 * np.nanpercentile(err, 95):.2f} mm,"
          f" max {1000 * np.nanmax(err):.2f} mm; worst joints "
          + ", ".join(f"{names[j]} {per[j]:.2f}" for j in worst))


def test_exact_capture_is_solved_exactly():
    cap, model, res, err = _run(CaptureOptions())
    assert (res.joint_quality == Quality.GOOD).all()
    assert err.max() < 1e-6
    par = cap.skeleton.joint_parent
    has = par >= 0
    true_len = np.linalg.norm(cap.base_joint_centres[has] - cap.base_joint_centres[par[has]], axis=-1)
    np.testing.assert_allclose(model.bone_length[has], true_len, atol=1e-6)
    assert np.isnan(model.bone_length[~has]).all()


def test_1mm_noise():
    cap, model, res, err = _run(CaptureOptions(noise_mm=1.0))
    _report("full body, 1 mm noise", err, model.joint_names)
    assert not model.warnings
    assert np.nanmean(err) <= 0.002


def test_soft_tissue_wobble():
    cap, model, res, err = _run(CaptureOptions(noise_mm=1.0, wobble_mm=2.0))
    _report("full body, 1 mm noise + 2 mm soft-tissue wobble", err, model.joint_names)
    assert np.nanmean(err) <= 0.005


@pytest.mark.parametrize("limb,hidden", [("lower_arm_l", ["LFRM", "LWRB"]),
                                         ("lower_leg_r", ["RTIB", "RSHB"]),
                                         ("hand_r", ["RHND", "RFIN"])])
def test_two_markers_of_a_limb_hidden(limb, hidden):
    cap, model, res, err = _run(CaptureOptions(noise_mm=1.0), hide=hidden)
    sk = cap.skeleton
    l = sk.limb_names.index(limb)
    joints = np.flatnonzero((sk.joint_limbs == l).any(1))
    assert (res.limb_quality[:, l] == Quality.MISSING).all()
    assert (res.joint_quality[:, joints] == Quality.ESTIMATED).all()
    e = err[:, joints]
    print(f"\n{limb} with {hidden} hidden: joints "
          + ", ".join(f"{sk.joint_names[j]} mean {1000 * np.mean(e[:, i]):.2f} max {1000 * np.max(e[:, i]):.2f} mm"
                      for i, j in enumerate(joints)))
    assert e.max() <= 0.010
