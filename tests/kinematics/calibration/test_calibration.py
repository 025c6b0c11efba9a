"""Calibration: hinge axes, joint points, model files, and clear errors on bad input."""
from __future__ import annotations

import copy
import dataclasses
import json
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.testing import arm_jig
from mocapgraph.kinematics.calibration.calibrate import (
    CalibrationError,
    CalibrationWarning,
    calibrate,
    find_base_pose,
    layout_markers,
)
from mocapgraph.kinematics.layout import LayoutError
from mocapgraph.kinematics.model import ModelFileError, load_model, save_model
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver


def _definition(layout=None) -> SkeletonDefinition:
    return SkeletonDefinition.from_layout_dict(layout or arm_jig.ARM_LAYOUT, "arm_jig")


def _gym(seed=0, n=600, amp=35.0, axes=None, base=arm_jig.BASE_A):
    rng = np.random.default_rng(seed)
    return arm_jig.forward(arm_jig.gym(rng, base, n, amp, axes))


def test_hinge_axis_and_centre_on_axis():
    layout = copy.deepcopy(arm_jig.ARM_LAYOUT)
    layout["limbs"][2]["joint"]["type"] = "hinge"
    axes = np.ones((4, 3))
    axes[2] = [0, 0, 1]  # forearm flexes about its local z only
    markers, joints = _gym(axes=axes)
    model = calibrate(_definition(layout), markers)
    true_axis = arm_jig.BASE_A[2] @ np.array([0.0, 0.0, 1.0])
    axis = model.hinge_axis[1]
    assert abs(axis @ true_axis) > 1 - 1e-9
    d = model.joint_base[1] - joints[0, 1]
    assert np.linalg.norm(d - (d @ axis) * axis) < 1e-6  # centre lies on the true axis
    assert model.quality.method[1] == "hinge+plane"
    assert np.isnan(model.hinge_axis[0]).all()


def test_hinge_centre_from_the_plane_of_its_neighbours_is_exact():
    # Elbow flexing about the normal of the shoulder-elbow-wrist plane (an anatomical hinge):
    # the centre along the axis comes from that plane and is exact.
    layout = copy.deepcopy(arm_jig.ARM_LAYOUT)
    layout["limbs"][2]["joint"]["type"] = "hinge"
    base = arm_jig.BASE_A.copy()
    base[2] = base[1] @ Rotation.from_euler("z", -35, degrees=True).as_matrix()
    axes = np.ones((4, 3))
    axes[2] = [0, 0, 1]
    markers, joints = _gym(axes=axes, base=base)
    model = calibrate(_definition(layout), markers)
    np.testing.assert_allclose(model.joint_base, joints[0], atol=1e-6)


def test_joint_point_limb_with_two_markers_is_exact():
    layout = copy.deepcopy(arm_jig.ARM_LAYOUT)
    layout["limbs"][1]["markers"] = ["UA1", "UA3"]
    layout["limbs"][1]["joint_points"] = ["shoulder"]
    definition = _definition(layout)
    markers, joints = _gym(n=800)
    full = ["CL1", "CL2", "CL3", "UA1", "UA2", "UA3", "FA1", "FA2", "FA3", "HA1", "HA2", "HA3"]
    ordered = layout_markers(definition, full, markers)
    assert ordered.shape[1] == 11
    model = calibrate(definition, ordered)
    assert model.quality.method[0] == "sphere"
    res = FrameSolver(model, max_gap_s=0).solve(ordered)
    assert np.nanmax(np.linalg.norm(res.joints - joints, axis=-1)) < 1e-6


def test_model_json_round_trip_and_layout_check(tmp_path):
    definition = _definition()
    markers, joints = _gym()
    model = calibrate(definition, markers, rate_hz=120.0)
    path = tmp_path / "actor.json"
    save_model(model, path)
    text = path.read_text()
    assert '"format": "mocapgraph.skeleton_model"' in text and '"version": 2' in text
    loaded = load_model(path, definition)
    np.testing.assert_allclose(loaded.offsets, model.offsets, atol=1e-7)
    np.testing.assert_allclose(loaded.bone_length, model.bone_length, atol=1e-7)
    a = FrameSolver(model).solve(markers[:50]).joints
    b = FrameSolver(loaded).solve(markers[:50]).joints
    np.testing.assert_allclose(a, b, atol=1e-6)

    other = SkeletonDefinition.from_layout_file("kiip_full_body")
    with pytest.raises(ModelFileError) as exc:
        load_model(path, other)
    msg = str(exc.value)
    assert "arm_jig" in msg and "kiip_full_body" in msg and str(path) in msg

    renamed = copy.deepcopy(arm_jig.ARM_LAYOUT)
    renamed["limbs"][0]["markers"] = ["CLX", "CL2", "CL3"]
    with pytest.raises(ModelFileError, match="CLX"):
        load_model(path, _definition(renamed))

    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something else"}))
    with pytest.raises(ModelFileError, match="not a skeleton model"):
        load_model(bad)
    with pytest.raises(ModelFileError, match="no such"):
        load_model(tmp_path / "absent.json")


def test_gym_without_motion_is_an_error_naming_joints():
    markers, _ = _gym(amp=0.5)
    with pytest.raises(CalibrationError) as exc:
        calibrate(_definition(), markers)
    msg = str(exc.value)
    assert "almost no motion" in msg and "shoulder" in msg and "elbow" in msg and "wrist" in msg


def test_one_stiff_joint_is_warned_and_flagged():
    axes = np.ones((4, 3))
    axes[3] = 0.02  # the hand hardly moves against the forearm
    markers, _ = _gym(axes=axes)
    with pytest.warns(CalibrationWarning, match="wrist"):
        model = calibrate(_definition(), markers)
    assert list(model.quality.reliable) == [True, True, False]
    assert model.warnings and "wrist" in model.warnings[0]


def test_base_pose_errors_name_markers():
    markers, _ = _gym(n=100)
    labels = _definition().marker_labels
    m = markers.copy()
    m[:, 4] = np.nan
    with pytest.raises(CalibrationError, match="never visible: UA2"):
        find_base_pose(m, labels)
    m = markers.copy()
    m[:60, 4] = np.nan
    assert find_base_pose(m, labels) == 60
    with pytest.raises(CalibrationError, match="first 30 frames"):
        calibrate(_definition(), m, rate_hz=100.0, max_base_search_s=0.3)
    m = markers.copy()
    m[::2, 0] = np.nan
    m[1::2, 1] = np.nan
    with pytest.raises(CalibrationError, match="no frame shows all markers at once"):
        find_base_pose(m, labels)


def test_layout_markers_missing_from_capture():
    definition = _definition()
    markers, _ = _gym(n=10)
    labels = list(definition.marker_labels)
    labels[7] = "SOMETHING"
    with pytest.raises(CalibrationError, match="lacks: FA2"):
        layout_markers(definition, labels, markers, source="trial.c3d")
    out = layout_markers(definition, labels, markers, allow_missing=True)
    assert np.isnan(out[:, 7]).all()
    # order and a Vicon subject prefix do not matter
    perm = np.random.default_rng(0).permutation(12)
    pref = [f"Subj:{definition.marker_labels[i]}" for i in perm]
    np.testing.assert_array_equal(layout_markers(definition, pref, markers[:, perm]), markers)


def test_limb_with_fewer_than_three_markers():
    layout = copy.deepcopy(arm_jig.ARM_LAYOUT)
    layout["limbs"][3]["markers"] = ["HA1", "HA2"]
    with pytest.raises(LayoutError, match="hand"):
        _definition(layout)
    # A definition built some other way is still checked by calibrate.
    definition = _definition()
    owner = definition.marker_limb.copy()
    owner[11] = 2
    thin = dataclasses.replace(definition, marker_limb=owner)
    markers, _ = _gym(n=50)
    with pytest.raises(CalibrationError, match=r"fewer than 3 markers.*hand \(2\)"):
        calibrate(thin, markers)


def test_wrong_marker_count_is_named():
    markers, _ = _gym(n=20)
    with pytest.raises(CalibrationError, match=r"expected \[T, 12, 3\]"):
        calibrate(_definition(), markers[:, :10])


def test_robust_weighting_ignores_glitch_frames():
    markers, _ = _gym(seed=3, n=800)
    clean = calibrate(_definition(), markers)
    glitched = markers.copy()
    rng = np.random.default_rng(5)
    bad = rng.choice(np.arange(1, 800), 40, replace=False)
    glitched[bad, 4] += rng.normal(scale=0.05, size=(40, 3))  # a marker jumps 5 cm in 5 % of frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        robust = calibrate(_definition(), glitched)
    shift = np.linalg.norm(robust.joint_base - clean.joint_base, axis=-1)
    print("joint centre shift from 5 % glitch frames (mm):", np.round(1000 * shift, 3))
    assert shift.max() < 0.001  # plain least squares moves them 2.5-2.8 mm
    assert robust.quality.outlier_fraction[:2].max() > 0.03
