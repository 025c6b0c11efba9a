"""The global per-frame fit against the synthetic actor's exact joint centres, beside the
segment-wise solver; live and batch agree; an occluded limb is held by its joints; real data."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from mocapgraph.formats.trc_file import read_trc
from mocapgraph.kinematics.calibration.calibrate import CalibrationWarning, calibrate, layout_markers
from mocapgraph.kinematics.model import Quality
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver

from global_fit_support import calibrated_actor


@pytest.mark.parametrize("layout", ["one_arm", "kiip_full_body"])
def test_global_fit_beats_the_segment_wise_solver_on_exact_ground_truth(layout):
    # one_arm: three markers per segment on small clusters off the bone, 1 mm noise.
    model, x, truth = calibrated_actor(layout)
    out = {}
    for fit in ("segment", "global"):
        res = FrameSolver(model, rate_hz=120.0, fit=fit).solve(x)
        e = np.linalg.norm(res.joints - truth, axis=-1)
        out[fit] = (e.mean(), e.max(), e.mean(0))
        assert (res.joint_quality == Quality.GOOD).all()
    print(f"\n{layout}, {len(x)} frames, 1 mm noise: per-frame joint error vs ground truth")
    for fit, (mean, mx, per) in out.items():
        print(f"  {fit:<8} mean {1000 * mean:.2f} mm, max {1000 * mx:.2f} mm; per joint mean "
              + " ".join(f"{1000 * v:.1f}" for v in per))
    mean, mx, _ = out["global"]
    assert mean <= 0.0015 and mx <= 0.005
    assert mean < out["segment"][0]


def test_live_steps_give_the_batch_result_and_an_occluded_limb_is_held_by_its_joints():
    model, x, truth = calibrated_actor("one_arm", seed=3)
    x = x[:240].copy()
    hand = model.limb_names.index("hand_r")
    own = [m for m in model.limb_markers[hand] if m >= 0 and model.marker_labels[m] in ("RFIN", "RHND")]
    x[100:140, own[0]] = np.nan  # the hand keeps one marker of its own plus the two shared ones
    forearm = model.limb_names.index("forearm_r")
    lost = [m for m in model.limb_markers[forearm] if m >= 0]
    x[160:170, lost[:2]] = np.nan  # forearm with one marker: its fit fails, the fit must not
    batch = FrameSolver(model, rate_hz=120.0, fit="global", max_gap_s=0.0).solve(x)
    live = FrameSolver(model, rate_hz=120.0, fit="global", max_gap_s=0.0)
    steps = np.array([live.step(f).joints for f in x])
    # Live frames start from the last frame's optimum, batch ones from the segment-wise fit:
    # both stop within the convergence tolerance (10 um of point motion) of the same optimum.
    assert (np.isnan(steps) == np.isnan(batch.joints)).all()
    assert np.nanmax(np.abs(steps - batch.joints)) < 2e-5
    e = np.linalg.norm(batch.joints - truth[:240], axis=-1)
    assert np.nanmax(e[100:140]) < 0.006
    elbow, wrist = model.joint_names.index("elbow_r"), model.joint_names.index("wrist_r")
    q = batch.joint_quality
    assert (q[160:170, [elbow, wrist]] == Quality.ESTIMATED).all()  # from one limb only
    assert np.nanmax(e[160:170, [elbow, wrist]]) < 0.01


def test_segment_lengths_on_a_real_walk_hold_better_with_the_global_fit(shared_data):
    folder = shared_data / "trc" / "opensim-gait2392"
    static = read_trc(folder / "subject01_static.trc")
    walk = read_trc(folder / "subject01_walk1.trc")
    definition = SkeletonDefinition.from_layout_file("opensim_gait2392")
    s = layout_markers(definition, static.labels, static.positions)
    w = layout_markers(definition, walk.labels, walk.positions, allow_missing=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        model = calibrate(definition, np.concatenate([s, w]), rate_hz=60.0, centre_order=("anatomical", "functional"),
                          parts=[("static", len(s)), ("walk", len(w))])
    idx = {n: i for i, n in enumerate(model.joint_names)}
    print("\nOpenSim subject01 walk, segment length std (no length correction), mm:")
    stds = {}
    for fit in ("segment", "global"):
        res = FrameSolver(model, rate_hz=60.0, enforce_lengths=False, fit=fit).solve(w)
        stds[fit] = {f"{a}-{b}_{x}": np.linalg.norm(res.joints[:, idx[f"{a}_{x}"]] - res.joints[:, idx[f"{b}_{x}"]],
                                                    axis=1).std()
                     for x in "lr" for a, b in (("hip", "knee"), ("knee", "ankle"))}
        print(f"  {fit:<8} " + "  ".join(f"{k} {1000 * v:.2f}" for k, v in stds[fit].items()))
    for k in stds["global"]:
        assert stds["global"][k] < stds["segment"][k]


def test_live_global_fit_recovers_from_a_lost_frame_and_a_jump_like_the_batch():
    # A frame with nothing seen, then the whole capture shifted 0.4 m and turned 30 deg (a
    # re-origined system): live frames restart from the segment-wise fit and track again, and
    # after the jump they are the unmoved capture's joints, moved.
    model, x0, _ = calibrated_actor("kiip_full_body", seed=4)
    x0 = x0[:160]
    reference = FrameSolver(model, rate_hz=120.0, fit="global", max_gap_s=0.0).solve(x0).joints
    x = x0.copy()
    x[60] = np.nan
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    turn = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    shift = np.array([0.4, -0.2, 0.0])
    x[100:] = x[100:] @ turn.T + shift
    batch = FrameSolver(model, rate_hz=120.0, fit="global", max_gap_s=0.0).solve(x)
    live = FrameSolver(model, rate_hz=120.0, fit="global", max_gap_s=0.0)
    out = [live.step(f) for f in x]
    joints = np.array([r.joints for r in out])
    quality = np.array([r.joint_quality for r in out])
    assert (quality == batch.joint_quality).all()
    assert (quality[60] == Quality.MISSING).all() and (np.delete(quality, 60, 0) == Quality.GOOD).all()
    assert np.nanmax(np.abs(joints - batch.joints)) < 2e-5
    assert np.abs(joints[:60] - reference[:60]).max() < 2e-5
    assert np.abs(joints[61:100] - reference[61:100]).max() < 2e-5
    assert np.abs(joints[100:] - (reference[100:] @ turn.T + shift)).max() < 2e-5
