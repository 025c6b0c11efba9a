"""The compiled live joint stage against its numpy reference: the segment-wise solver's live
frames (gap filling and bone lengths on, occlusions) give the same joints and qualities."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
from mocapgraph.kinematics.model import Quality
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor


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


def test_compiled_joint_stage_gives_the_numpy_reference_on_a_real_walk(shared_data):
    # OpenSim subject01: static with medial markers + walk without them (real marker noise and gaps).
    from mocapgraph.formats.trc_file import read_trc
    from mocapgraph.kinematics.calibration.calibrate import layout_markers
    from mocapgraph.kinematics.skeleton import SkeletonDefinition

    folder = shared_data / "trc" / "opensim-gait2392"
    static, walk = read_trc(folder / "subject01_static.trc"), read_trc(folder / "subject01_walk1.trc")
    definition = SkeletonDefinition.from_layout_file("opensim_gait2392")
    s = layout_markers(definition, static.labels, static.positions)
    w = layout_markers(definition, walk.labels, walk.positions, allow_missing=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(definition, np.concatenate([s, w]), rate_hz=60.0, centre_order=("anatomical", "functional"),
                          parts=[("static", len(s)), ("walk", len(w))])
    out = {}
    for compiled in (False, True):
        # The torso cluster fits to 40 mm here: a looser limb tolerance lets most frames take the
        # fully-seen path (the one compiled).
        solver = FrameSolver(model, rate_hz=60.0, limb_rms_tol=0.05, compiled=compiled)
        assert solver._kernel_joints == compiled
        res = [solver.step(f) for f in w]
        out[compiled] = np.array([r.joints for r in res]), np.array([r.joint_quality for r in res])
    (rj, rq), (kj, kq) = out[False], out[True]
    # Most frames take the compiled path (every limb seen and fit well).
    assert (np.array([(r.limb_quality == Quality.GOOD).all() for r in res])).mean() > 0.5
    assert (rq == kq).all() and (np.isnan(rj) == np.isnan(kj)).all()
    assert np.nanmax(np.abs(rj - kj)) < 1e-12
