"""Honest range of motion and quality: a still subject does not move, and a joint whose centre
calibration could not determine is never flagged good by the solver."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapgraph.formats.c3d_file import read_c3d
from mocapgraph.kinematics.calibration.calibrate import (
    CalibrationError,
    CalibrationWarning,
    calibrate,
    joint_range_of_motion,
    layout_markers,
)
from mocapgraph.kinematics.model import Quality
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript


def _still(layout: str, frames: int = 600):
    actor = SyntheticActor(layout, rate=120.0, seed=5, script=MotionScript(gym_block_s=2.0, gym_scale=0.0),
                           options=CaptureOptions(noise_mm=1.0))
    return actor.skeleton, actor.capture(0, frames).markers


@pytest.mark.parametrize("layout", ["kiip_full_body", "opensim_gait2392", "one_arm"])
def test_a_still_subject_has_no_range_of_motion(layout):
    definition, markers = _still(layout)
    rom = np.degrees(joint_range_of_motion(definition, markers))
    print(f"\n{layout} still, 1 mm noise: ROM deg " + " ".join(f"{n} {r:.1f}" for n, r in
                                                         zip(definition.joint_names, rom)))
    assert rom.max() < 5.0
    if not any(definition.joint_landmarks):
        with pytest.raises(CalibrationError, match="almost no motion"):
            calibrate(definition, markers, rate_hz=120.0)
        return
    # With landmarks a static alone calibrates: anatomical centres are reliable, nothing else is.
    with pytest.warns(CalibrationWarning, match="no reliable centre"):
        model = calibrate(definition, markers, rate_hz=120.0)
    q = model.quality
    anat = np.array([m == "landmarks" for m in q.method])
    assert anat.sum() == sum(1 for lm in definition.joint_landmarks if lm)
    assert (q.reliable == anat).all()


def test_the_real_static_is_still_through_the_two_marker_limbs(shared_data):
    # Plug-in Gait thighs and upper arms have two markers: their ROM once came through the
    # estimated joint point and a standing subject "moved" 33-180 deg.
    st = read_c3d(shared_data / "c3d" / "pycgm" / "Static_trial.c3d")
    definition = SkeletonDefinition.from_layout_file("plug_in_gait")
    x = layout_markers(definition, st.labels, st.positions)
    rom = np.degrees(joint_range_of_motion(definition, x))
    print("\npyCGM static ROM deg: " + " ".join(f"{n} {r:.1f}" for n, r in zip(definition.joint_names, rom)))
    assert rom.max() < 12.0  # a real person sways a little; far below the 25 deg of a functional centre
    two = [definition.joint_index(n) for n in ("hip_l", "hip_r", "shoulder_r", "knee_l", "knee_r")]
    assert rom[two].max() < 5.0


def test_an_unreliable_joint_is_never_flagged_good():
    actor = SyntheticActor("kiip_full_body", rate=60.0, seed=1, script=MotionScript(gym_block_s=1.0),
                           options=CaptureOptions(noise_mm=1.0))
    cap = actor.capture(0, 600)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(actor.skeleton, cap.markers, rate_hz=60.0, min_rom_deg=60.0)
    bad = ~model.quality.reliable
    assert bad.any() and not bad.all()
    res = FrameSolver(model, rate_hz=60.0).solve(cap.markers)
    q = res.joint_quality
    assert (q[:, bad] != Quality.GOOD).all()
    assert (q[:, bad] == Quality.ESTIMATED).mean() > 0.99  # still solved, just not called good
    assert (q[:, ~bad] == Quality.GOOD).mean() > 0.99
