"""Issue 27: every centre with an honest standard error; degenerate clusters solved, not abandoned.

Random virtual arms (:mod:`mocapgraph.testing.random_jig`) on seeds the code was not tuned on
(tuning used seeds 100-102): 1 mm Gaussian noise per marker coordinate, a 1440-frame range of
motion at 120 Hz sweeping every joint about every axis, five held test poses.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate
from mocapgraph.kinematics.model import ActorModel, load_model, save_model
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.testing.random_jig import issue_arm, random_jig

NOISE = 0.001


def _trial(seed: int, collinear: int | None = None, rom=70.0, hinge_share: float = 0.0):
    rng = np.random.default_rng(seed)
    jig = random_jig(rng, collinear=collinear, hinge_share=hinge_share)
    definition = SkeletonDefinition.from_layout_dict(jig.layout(), "random_jig")
    clean, joints = jig.forward(jig.rom_trial(rng, 1440, rom))
    noisy = clean + rng.normal(scale=NOISE, size=clean.shape)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(definition, noisy, rate_hz=120.0)
    # The calibration's error: the model's centres on the noise-free base pose, against truth.
    centre = FrameSolver(model, max_gap_s=0, enforce_lengths=False).solve(clean[:1]).joints[0]
    pose_m, pose_j = jig.forward(jig.test_poses(rng, 5), origin=np.array([0.3, -0.1, 1.2]))
    pose_m = pose_m + rng.normal(scale=NOISE, size=pose_m.shape)
    return jig, model, centre - joints[0], pose_m, pose_j


def test_predicted_standard_errors_are_honest():
    # True error within 3 predicted standard errors for >= 99 % of joints (a hinge: across its
    # axis, which is what its standard error covers), over plain, near-collinear and hinged arms.
    ratios = []
    for seed in range(700, 736):
        kind = seed % 3
        jig, model, err, _, _ = _trial(seed, collinear=3 if kind == 1 else None, hinge_share=0.5 if kind == 2 else 0.0)
        axes = model.hinge_axis
        for j in range(model.n_joints):
            e = err[j]
            if model.joint_hinge[j]:
                e = e - (e @ axes[j]) * axes[j]
            ratios.append(np.linalg.norm(e) / model.quality.centre_se[j])
    ratios = np.array(ratios)
    print(f"\n{ratios.size} joints: error / predicted SE median {np.median(ratios):.2f}, "
          f"p95 {np.quantile(ratios, 0.95):.2f}, max {ratios.max():.2f}")
    assert np.isfinite(ratios).all()
    assert np.mean(ratios <= 3.0) >= 0.99
    # ... and not honest by being vague: the median ratio is near 1 (not 0.1).
    assert np.median(ratios) > 0.4


@pytest.mark.parametrize("collinear", [3])
def test_near_collinear_cluster_is_solved_from_its_markers_as_points(collinear):
    for seed in (801, 802, 803):
        jig, model, err, pose_m, pose_j = _trial(seed, collinear=collinear)
        q = model.quality
        res = FrameSolver(model, max_gap_s=0, fit="global").solve(pose_m)
        e = np.linalg.norm(res.joints - pose_j, axis=-1)
        print(f"\nseed {seed} collinear segment {collinear}: centre error mm {np.round(1000 * np.linalg.norm(err, axis=-1), 2)} "
              f"SE mm {np.round(1000 * q.centre_se, 2)} methods {q.method}; poses mean {1000 * e.mean():.2f} max {1000 * e.max():.2f} mm")
        assert (np.linalg.norm(err, axis=-1) <= 0.002).all()
        assert q.reliable.all() and (res.joint_quality == 2).all()
        # Issue 27 asks mean <= 1.5 mm, max <= 5 mm: measured 1.29 / 1.25 / 1.47 mm, max 1.9-2.8 mm
        # (803 gave 2.04 mm while the hand's model held the wrist where the forearm's base frame
        # put it, 3.6-4.9 mm short of the hand markers' own distances; see calibrate._own_point).
        assert e.mean() <= 0.0015 and e.max() <= 0.005
        # The joints next to the line-like cluster were found from its markers as points, and say so.
        near = [j for j in range(model.n_joints) if collinear in model.joint_limbs[j]]
        assert all(q.from_points[j] and "cannot fix its orientation" in q.inputs[j]["points"] for j in near)


def test_a_joint_that_hardly_moved_is_flagged_with_its_error_in_mm():
    rom = np.array([70.0, 70.0, 70.0, 12.0])   # the hand barely moves against the forearm
    with pytest.warns(CalibrationWarning, match=r"wrist \d+\.\d deg, \+-\d+\.\d mm"):
        rng = np.random.default_rng(901)
        jig = random_jig(rng)
        clean, _ = jig.forward(jig.rom_trial(rng, 1440, rom))
        model = calibrate(SkeletonDefinition.from_layout_dict(jig.layout(), "random_jig"),
                          clean + rng.normal(scale=NOISE, size=clean.shape), rate_hz=120.0)
    q = model.quality
    assert not q.reliable[2] and np.isfinite(q.centre_se[2]) and q.centre_se[2] > model.max_uncertainty
    assert q.reliable[:2].all()


def test_uncertainty_is_in_the_model_file_and_a_version_1_file_still_loads(tmp_path):
    _, model, _, _, _ = _trial(950)
    path = tmp_path / "m.json"
    save_model(model, path)
    back = load_model(path)
    np.testing.assert_allclose(back.quality.centre_se, model.quality.centre_se, rtol=1e-5)
    assert abs(back.marker_noise - NOISE) < 0.1 * NOISE   # the noise found from the clusters' residuals
    d = json.loads(path.read_text())
    d["version"] = 1
    for jt in d["joints"]:
        for k in ("centre_se", "centre_cov", "axis_se_rad", "from_points"):
            jt["quality"].pop(k)
    for k in ("marker_noise", "max_uncertainty"):
        d.pop(k)
    old = ActorModel.from_dict(d)
    assert np.isnan(old.quality.centre_se).all() and not old.quality.from_points.any()
    np.testing.assert_array_equal(old.joint_base, back.joint_base)


def test_uncertainty_travels_in_the_messages_and_per_frame_in_actor_pose():
    from mocapgraph.adapters.model_messages import model_from_message, model_to_message, pose_message, quality_table
    from mocapgraph.messages.codec import decode, encode

    jig, model, _, _, _ = _trial(960, collinear=3)
    _, msg = decode([bytes(f) for f in encode("skeleton_model", model_to_message(model), 1, 0)])
    back = model_from_message(msg)
    np.testing.assert_array_equal(back.quality.centre_se, model.quality.centre_se)
    np.testing.assert_array_equal(back.quality.from_points, model.quality.from_points)
    table = quality_table(back)
    print("\n" + table)
    assert "+-SE mm" in table and "(points)" in table and "marker noise" in table
    # Per frame: a fresh noisy trial solved by the model from the message; each joint's error is
    # within 3 of its reported uncertainties in >= 95 % of frames (segment-wise solve).
    rng = np.random.default_rng(961)
    clean, joints = jig.forward(jig.rom_trial(rng, 300, 60.0))
    res = FrameSolver(back, max_gap_s=0).solve(clean + rng.normal(scale=NOISE, size=clean.shape))
    err = np.linalg.norm(res.joints - joints, axis=-1)
    u = res.joint_uncertainty
    print("per-frame error rms mm", np.round(1000 * np.sqrt((err ** 2).mean(0)), 2),
          "reported uncertainty mean mm", np.round(1000 * u.mean(0), 2))
    assert ((err <= 3 * u).mean(0) >= 0.95).all()
    assert (u.mean(0) < 3 * np.sqrt((err ** 2).mean(0))).all()   # not honest by being vague
    _, pose = decode([bytes(f) for f in encode("actor_pose", pose_message(res[7], "a", 7), 1, 0)])
    np.testing.assert_array_equal(pose.joint_uncertainty, u[7])


def test_a_stiff_joint_is_never_good_and_its_uncertainty_says_why():
    rom = np.array([70.0, 70.0, 70.0, 12.0])
    rng = np.random.default_rng(970)
    jig = random_jig(rng)
    clean, joints = jig.forward(jig.rom_trial(rng, 1440, rom))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(SkeletonDefinition.from_layout_dict(jig.layout(), "random_jig"),
                          clean + rng.normal(scale=NOISE, size=clean.shape), rate_hz=120.0)
    res = FrameSolver(model, max_gap_s=0).solve(clean[:50] + rng.normal(scale=NOISE, size=clean[:50].shape))
    assert (res.joint_quality[:, 2] == 1).all() and (res.joint_quality[:, :2] == 2).all()
    assert (res.joint_uncertainty[:, 2] > model.max_uncertainty).all()


def test_a_marker_lost_for_the_whole_trial_leaves_its_limb_fitted_through_its_joint():
    rng = np.random.default_rng(980)
    jig = random_jig(rng)
    definition = SkeletonDefinition.from_layout_dict(jig.layout(), "random_jig")
    clean, joints = jig.forward(jig.rom_trial(rng, 1440, 70.0))
    noisy = clean + rng.normal(scale=NOISE, size=clean.shape)
    lost = definition.marker_labels.index("S3M1")   # a hand marker never seen
    noisy[:, lost] = np.nan
    with pytest.warns(CalibrationWarning, match="never seen.*S3M1.*hand fitted through its joints"):
        model = calibrate(definition, noisy, rate_hz=120.0)
    q = model.quality
    err = FrameSolver(model, max_gap_s=0, enforce_lengths=False).solve(clean[:1]).joints[0] - joints[0]
    print(f"\nlost S3M1: centre error mm {np.round(1000 * np.linalg.norm(err, axis=-1), 2)}, "
          f"SE mm {np.round(1000 * q.centre_se, 2)}, methods {q.method}")
    assert q.from_points[2] and q.reliable.all() and (np.linalg.norm(err, axis=-1) <= 0.002).all()
    pose_m, pose_j = jig.forward(jig.test_poses(rng, 5), origin=np.array([0.3, -0.1, 1.2]))
    pose_m = pose_m + rng.normal(scale=NOISE, size=pose_m.shape)
    pose_m[:, lost] = np.nan
    res = FrameSolver(model, max_gap_s=0, fit="global").solve(pose_m)
    e = np.linalg.norm(res.joints - pose_j, axis=-1)
    print(f"poses (global fit): mean {1000 * e.mean():.2f} max {1000 * e.max():.2f} mm")
    assert (res.joint_quality == 2).all() and e.max() <= 0.005


@pytest.mark.parametrize("collinear", [None, 3])
def test_issue_arm_global_fit_meets_the_target_at_the_maximum_likelihood_floor(collinear):
    # Issue 27's arm on seeds no code was tuned on (6100-6101; benchmarks/accuracy.py runs
    # 6000-6019): per-frame error mean <= 1.5 mm, max <= 5 mm on the held poses and on a fresh
    # 240-frame trial, and on the trial within 5 % of the same frames fitted by the TRUE geometry
    # at maximum-likelihood weights (what any per-frame fit can reach with this noise). Before
    # the joint-point fix, a line-like hand's arm was 70 % over that floor (2.11 vs 1.25 mm).
    for seed in (6100, 6101):
        a = issue_arm(seed, collinear)
        print(f"\nseed {seed} collinear {collinear}: poses {1e3 * a.poses.mean():.2f}/{1e3 * a.poses.max():.2f} mm, "
              f"trial {1e3 * a.trial.mean():.2f}/{1e3 * a.trial.max():.2f} mm, ML floor {1e3 * a.trial_ml.mean():.2f} mm")
        assert a.poses.mean() <= 0.0015 and a.poses.max() <= 0.005
        assert a.trial.mean() <= 0.0015 and a.trial.max() <= 0.005
        assert a.trial.mean() <= 1.05 * a.trial_ml.mean() + 2e-5


@pytest.mark.parametrize("seed", [6102, 6103])
def test_low_passed_markers_beat_the_one_frame_floor_and_keep_the_uncertainty_honest(seed):
    # A single frame cannot beat its maximum-likelihood floor (five of 20 line-like-hand arms
    # reach 5.2-7.8 mm there); the low-pass uses the frames around it. On fresh seeds: poses held
    # 0.5 s and a fast 60-degree trial, both within mean 1.5 / max 5 mm, the trial's mean well
    # under the one-frame floor, and its reported uncertainty still covering the true error.
    a = issue_arm(seed, 3)
    print(f"\nseed {seed}: held {1e3 * a.held_lowpass.mean():.2f}/{1e3 * a.held_lowpass.max():.2f} mm "
          f"(cutoff {a.cutoff_hz[0]} Hz), trial {1e3 * a.trial_lowpass.mean():.2f}/{1e3 * a.trial_lowpass.max():.2f} mm "
          f"(cutoff {a.cutoff_hz[1]} Hz) against one frame {1e3 * a.trial.mean():.2f}/{1e3 * a.trial.max():.2f}, "
          f"floor {1e3 * a.trial_ml.mean():.2f}")
    for e in (a.held_lowpass, a.trial_lowpass):
        assert e.mean() <= 0.0015 and e.max() <= 0.005
    assert a.trial_lowpass.mean() <= 0.8 * a.trial_ml.mean()
    ratio = a.trial_lowpass / a.trial_lowpass_unc
    assert (ratio <= 3.0).mean() >= 0.99                             # honest
    assert np.median(ratio) >= 0.3                                  # and not vague
