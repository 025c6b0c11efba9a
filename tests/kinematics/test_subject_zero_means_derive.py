"""A VSK measurement of 0 means "derive it" (Vicon writes 0 for an unmeasured value): the hip centres
are those of the same subject with the field left out, not those of a 0 m measurement.

Vicon's own subject files carry ``LeftAsisTrocanterDistance VALUE="0"`` when the distance was not
measured (its EXPRESSION, 0.1288 LegLength - 48.56 mm, is what Nexus then uses); the Davis hip
takes that distance straight into the centre, so a 0 read as 0 m moves the hip by centimetres.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.subject import read_vsk
from mocapgraph.kinematics.synthetic.actor import SyntheticActor

RATE_HZ = 120.0
MEASURED = {"LeftLegLength": 877, "RightLegLength": 866, "LeftKneeWidth": 144, "RightKneeWidth": 139,
            "LeftAnkleWidth": 85, "RightAnkleWidth": 89}
#: what Vicon writes for measurements nobody took (derived from the markers or the leg length)
ZEROS = {"InterAsisDistance": 0, "LeftAsisTrocanterDistance": 0, "RightAsisTrocanterDistance": 0}


def _vsk(path: Path, values: dict[str, float]) -> Path:
    params = "\n".join(f'    <StaticParameter NAME="{k}" VALUE="{v}" PRIOR="0" REQUIRED="false" QUANTITY="length"/>'
                       for k, v in values.items())
    path.write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n<KinematicModel VERSION="1.0">\n'
                    f"  <Parameters>\n{params}\n  </Parameters>\n</KinematicModel>\n")
    return path


def _hips(capture, subject):
    """(hip_l, hip_r) calibrated inputs and the solved hip centres [T,2,3] of ``capture``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)   # the arms: no regression there, a prior
        model = calibrate(capture.skeleton, capture.markers, rate_hz=RATE_HZ, subject=subject,
                          centre_order=("regression",))
    hips = [capture.skeleton.joint_index(n) for n in ("hip_l", "hip_r")]
    assert all(model.quality.method[j] == "regression:pig_hip" for j in hips), model.quality.method
    solved = FrameSolver(model, rate_hz=RATE_HZ).solve(capture.markers).joints[:, hips]
    return [model.quality.inputs[j] for j in hips], solved


@pytest.fixture(scope="module")
def standing():
    """A second of a synthetic subject in Plug-in Gait markers (exact data), standing in its base pose."""
    return SyntheticActor("plug_in_gait", rate=RATE_HZ, seed=3).capture(0, int(RATE_HZ))


def test_a_zero_asis_trochanter_distance_is_derived_from_the_leg_length(tmp_path: Path, standing) -> None:
    zero = read_vsk(_vsk(tmp_path / "zero.vsk", {**MEASURED, **ZEROS}))
    absent = read_vsk(_vsk(tmp_path / "absent.vsk", MEASURED))
    assert (zero.asis_trochanter_l, zero.asis_trochanter_r, zero.inter_asis) == (None, None, None)
    assert replace(zero, source="") == replace(absent, source="")

    (in_l, in_r), hips_zero = _hips(standing, zero)
    (ab_l, ab_r), hips_absent = _hips(standing, absent)
    # Davis' estimate from each side's leg length, as Vicon's EXPRESSION gives it
    assert in_l["asis_trochanter_m"] == pytest.approx(0.1288 * 0.877 - 0.04856)
    assert in_r["asis_trochanter_m"] == pytest.approx(0.1288 * 0.866 - 0.04856)
    assert (in_l["local_m"], in_r["local_m"]) == (ab_l["local_m"], ab_r["local_m"])
    np.testing.assert_array_equal(hips_zero, hips_absent)

    # what taking the 0 as 0 m would give: hips some centimetres off, on every frame
    (z_l, _), hips_0m = _hips(standing, replace(absent, asis_trochanter_l=0.0, asis_trochanter_r=0.0))
    assert z_l["asis_trochanter_m"] == 0.0
    off = np.linalg.norm(hips_0m - hips_zero, axis=-1)
    assert np.all(off > 0.03), f"a 0 m distance moves the hips by only {off.min() * 1000:.1f} mm"
