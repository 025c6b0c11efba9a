"""The compiled live joint stage against its numpy reference: the segment-wise solver's live
frames (gap filling and bone lengths on, occlusions) give the same joints and qualities."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapgraph.kinematics.calibration import CalibrationWarning, calibrate
from mocapgraph.kinematics.solver import FrameSolver
from mocapgraph.kinematics.synthetic_actor import CaptureOptions, SyntheticActor


@pytest.mark.parametrize("layout", ["one_arm", "kiip_full_body"])
@pytest.mark.parametrize("enforce_lengths", [True, False])
def test_compiled_joint_stage_gives_the_numpy_reference(layout, enforce_lengths):
    actor = SyntheticActor(layout, rate=120.0, seed=5, options=CaptureOptions(noise_mm=1.0))
    cap = actor.capture()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(actor.skeleton, cap.markers[: cap.phases["gym"][1]:3], rate_hz=40.0)
    x = cap.markers[cap.phase_slice("performance")][:400].copy()
    x[50:60, :3] = np.nan                            # limbs lost: the general path, gap filling
    out = {}
    for compiled in (False, True):
        s = FrameSolver(model, rate_hz=120.0, enforce_lengths=enforce_lengths, compiled=compiled)
        assert s._kernel_joints == compiled
        res = [s.step(f) for f in x]
        out[compiled] = (np.array([r.joints for r in res]), np.array([r.joint_quality for r in res]),
                         np.array([r.limb_quality for r in res]))
    (rj, rq, rl), (kj, kq, kl) = out[False], out[True]
    assert (rq == kq).all() and (rl == kl).all()
    assert (np.isnan(rj) == np.isnan(kj)).all()
    assert np.nanmax(np.abs(rj - kj)) < 1e-12
    # The reference moved: the length correction is applied (or not) in both.
    truth = cap.joint_centres[cap.phase_slice("performance")][:400]
    assert np.nanmean(np.linalg.norm(kj - truth, axis=-1)) < 0.005
