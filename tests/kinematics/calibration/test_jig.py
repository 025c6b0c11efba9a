"""Kiip section 7.1 reproduced: a virtual arm jig (clavicle, shoulder, elbow, wrist).

Four rigid limbs (clavicle, upper arm, forearm, hand) with exactly three markers each. Only the
shoulder, elbow and wrist are computed (the clavicle limb provides the shoulder's second limb).
Five test poses with every joint rotated; the base pose changes after the third test, so tests
4-5 come from a second calibration. Joint errors per test are printed like Kiip's Table 3,
beside Kiip's SVD column (cm).
"""
from __future__ import annotations

import numpy as np

from mocapgraph.testing import arm_jig
from mocapgraph.kinematics.calibration.calibrate import calibrate
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver

# Kiip Table 3, "SVD Error" column (cm), shoulder/elbow/wrist per test; Kiip's own summary:
# overall mean 0.898 cm, maximum 1.354 cm.
KIIP_SVD_CM = np.array([[0.505, 0.757, 0.984], [0.892, 1.354, 1.194], [0.425, 0.903, 1.210],
                        [0.425, 0.903, 1.210], [0.661, 1.082, 0.999]])


def run_jig(noise_m: float, seed: int = 7, gym_frames: int = 1200, amp_deg: float = 35.0):
    """Kiip's five tests; returns errors [5, 3] (m) and the two calibrated models."""
    rng = np.random.default_rng(seed)
    definition = SkeletonDefinition.from_layout_dict(arm_jig.ARM_LAYOUT, "arm_jig")
    errors, models = [], []
    for base, tests in ((arm_jig.BASE_A, 3), (arm_jig.BASE_B, 2)):
        gym_m, _ = arm_jig.forward(arm_jig.gym(rng, base, gym_frames, amp_deg))
        gym_m = gym_m + rng.normal(scale=noise_m, size=gym_m.shape)
        model = calibrate(definition, gym_m, rate_hz=120.0)
        models.append(model)
        pose_m, truth = arm_jig.forward(arm_jig.random_poses(rng, base, tests),
                                        origin=np.array([0.3, -0.1, 1.2]))
        pose_m = pose_m + rng.normal(scale=noise_m, size=pose_m.shape)
        res = FrameSolver(model, max_gap_s=0).solve(pose_m)
        assert (res.joint_quality == 2).all()
        errors.append(np.linalg.norm(res.joints - truth, axis=-1))
    return np.concatenate(errors), models


def _table(err_m: np.ndarray, title: str) -> str:
    lines = [title, f"{'test':<6}{'joint':<10}{'ours (cm)':>10}{'Kiip SVD (cm)':>15}"]
    for i in range(5):
        for j, name in enumerate(("shoulder", "elbow", "wrist")):
            lines.append(f"{i + 1:<6}{name:<10}{100 * err_m[i, j]:>10.4f}{KIIP_SVD_CM[i, j]:>15.3f}")
    lines.append(f"{'mean':<16}{100 * err_m.mean():>10.4f}{0.898:>15.3f}")
    lines.append(f"{'max':<16}{100 * err_m.max():>10.4f}{1.354:>15.3f}")
    return "\n".join(lines)


def test_jig_noise_free_is_exact():
    err, models = run_jig(noise_m=0.0)
    print("\n" + _table(err, "Kiip jig, noise-free (Table 3 layout)"))
    assert err.max() < 1e-6
    for m in models:
        # elbow-shoulder = upper arm, wrist-elbow = forearm
        np.testing.assert_allclose(m.bone_length[1:], arm_jig.BONES[1:3], atol=1e-6)
        assert m.quality.reliable.all() and m.quality.residual_rms.max() < 1e-6


def test_jig_with_1mm_noise():
    err, models = run_jig(noise_m=0.001)
    print("\n" + _table(err, "Kiip jig, 1 mm Gaussian marker noise"))
    rom = np.degrees(np.concatenate([m.quality.range_of_motion for m in models]))
    print("range of motion per joint (deg):", np.round(rom, 1))
    assert rom.min() >= 45.0
    assert err.mean() <= 0.002
    assert err.max() <= 0.004
