"""The synthetic session the global-fit tests share: a calibrated model and its performance frames."""
from __future__ import annotations

import warnings

import numpy as np

from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
from mocapgraph.kinematics.model import ActorModel
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor


def calibrated_actor(layout: str, seed: int = 2) -> tuple[ActorModel, np.ndarray, np.ndarray]:
    """(model calibrated from every other gym frame, performance markers float[T,M,3] m, their
    true joint centres float[T,J,3] m) of a synthetic actor at 120 Hz with 1 mm marker noise."""
    actor = SyntheticActor(layout, rate=120.0, seed=seed, options=CaptureOptions(noise_mm=1.0))
    cap = actor.capture()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(actor.skeleton, cap.markers[: cap.phases["gym"][1]:2], rate_hz=60.0)
    perf = cap.phase_slice("performance")
    return model, cap.markers[perf], cap.joint_centres[perf]
