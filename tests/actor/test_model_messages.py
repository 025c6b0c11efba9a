"""The glue between kinematics and messages: exact model round trip, label placement, poses."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from actor_support import quick_model
from mocapgraph.kinematics.layout import available_layouts
from mocapgraph.kinematics.model import ModelFileError
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.messages import decode, encode
from mocapgraph.adapters.model_messages import (ModelMismatchError, marker_index, model_from_message,
                                             model_to_message, owner_limbs, pose_message)


@pytest.fixture(scope="module")
def kiip_model():
    return quick_model("kiip_full_body")


def _wire(msg):
    """Through the real codec, as a subscriber receives it."""
    return decode([bytes(f) for f in encode("skeleton_model", msg, 1, 0, "test")])[1]


def test_model_survives_the_wire_exactly(kiip_model):
    m = kiip_model
    back = model_from_message(_wire(model_to_message(m)))
    for f in ("base_markers", "limb_centroid", "offsets", "joint_base", "bone_length", "hinge_axis", "limb_rms",
              "limb_markers", "limb_joint_points", "limb_parent", "joint_limbs", "joint_parent", "joint_hinge"):
        np.testing.assert_array_equal(getattr(back, f), getattr(m, f), err_msg=f)
    for f in ("residual_rms", "range_of_motion", "n_frames", "outlier_fraction", "reliable"):
        np.testing.assert_array_equal(getattr(back.quality, f), getattr(m.quality, f), err_msg=f)
    assert back.quality.method == m.quality.method and back.marker_fingerprint == m.marker_fingerprint
    assert (back.layout, back.marker_labels, back.joint_names) == (m.layout, m.marker_labels, m.joint_names)
    cap = SyntheticActor("kiip_full_body", rate=60.0, options=CaptureOptions(noise_mm=1.0)).capture(400, 600)
    a = FrameSolver(m).solve(cap.markers)
    b = FrameSolver(back).solve(cap.markers)
    np.testing.assert_array_equal(a.joints, b.joints)
    err = np.linalg.norm(a.joints - cap.joint_centres, axis=-1)
    assert np.nanmean(err) < 0.005


@pytest.mark.parametrize("layout", available_layouts())
def test_marker_owners_from_the_fit_sets_match_the_layout(layout):
    sk = SkeletonDefinition.from_layout_file(layout)
    fake = SimpleNamespace(limb_markers=sk.limb_marker_index(), marker_labels=sk.marker_labels)
    np.testing.assert_array_equal(owner_limbs(fake), sk.marker_limb)


def test_stream_labels_are_placed_by_name_in_any_order(kiip_model):
    labels = list(kiip_model.marker_labels)
    rng = np.random.default_rng(1)
    order = rng.permutation(len(labels))
    stream = ["Subject:" + labels[i].lower() for i in order] + ["EXTRA"]
    where = marker_index(kiip_model, "", stream)
    assert [stream[w] for w in where] == ["Subject:" + s.lower() for s in labels]


def test_model_from_another_layout_is_refused_with_both_names(kiip_model):
    arm = quick_model("one_arm")
    with pytest.raises(ModelMismatchError) as e:
        marker_index(arm, "kiip_full_body", kiip_model.marker_labels, source="solver")
    msg = str(e.value)
    assert "'one_arm'" in msg and "'kiip_full_body'" in msg and "lacks 1 of its 12 markers (CLAV)" in msg and "\n" not in msg
    lab = [l for l in kiip_model.marker_labels if l not in ("LKNE", "RANK")]
    with pytest.raises(ModelMismatchError, match="lacks 2 of the 62 markers of model 'kiip_full_body': LKNE, RANK"):
        marker_index(kiip_model, "kiip_full_body", lab)


def test_broken_message_is_a_one_line_model_error(kiip_model):
    msg = model_to_message(kiip_model)
    msg.extra_json = '{"format": "something else"}'
    with pytest.raises(ModelFileError, match="malformed skeleton model"):
        model_from_message(msg)


def test_pose_message_carries_quality_and_nan(kiip_model):
    cap = SyntheticActor("kiip_full_body", rate=60.0).capture(400, 401)
    x = cap.markers[0].copy()
    sk = cap.skeleton
    hand = sk.limb_names.index("hand_l")
    x[np.flatnonzero(sk.marker_limb == hand)] = np.nan
    res = FrameSolver(kiip_model, max_gap_s=0).step(x)
    pose = pose_message(res, "a", 7)
    assert pose.limb_quality[hand] == 0 and np.isnan(pose.limb_orientations[hand]).all()
    assert pose.limb_visible_markers[hand] == len(sk.limb_markers(hand)) - np.isin(
        sk.limb_markers(hand), np.flatnonzero(sk.marker_limb == hand)).sum()
    ok = pose.limb_quality == 2
    np.testing.assert_allclose(np.linalg.norm(pose.limb_orientations[ok], axis=1), 1.0)


@pytest.mark.parametrize("layout", ["kiip_full_body", "plug_in_gait"])
def test_a_solver_fed_the_synthetic_ground_truth_model_solves_the_true_joints(layout):
    """The synthetic actor's ground_truth_model topic, through the wire, solves noise-free markers
    to the synthetic joint centres (the ground truth the generator computed, not our solver)."""
    from mocapgraph.nodes.synthetic_actor import ground_truth_model

    actor = SyntheticActor(layout, rate=100.0, seed=3)
    cap = actor.capture(0, 200)
    msg = _wire(ground_truth_model(cap, layout))
    model = model_from_message(msg, source="ground_truth_model")       # refused before: never solved
    assert model.layout == layout and list(model.marker_labels) == list(cap.skeleton.marker_labels)
    res = FrameSolver(model, rate_hz=100.0, max_gap_s=0.0).solve(cap.markers)
    exact = cap.limb_exact[np.asarray(cap.skeleton.joint_limbs)].all(1)   # joints of rigid limbs only
    err = np.linalg.norm(res.joints - cap.joint_centres, axis=-1)[:, exact]
    print(f"{layout}: ground-truth model, {exact.sum()} joints, max error {err.max() * 1e6:.3f} um")
    assert exact.sum() >= 4 and np.isfinite(err).all() and err.max() < 1e-6
