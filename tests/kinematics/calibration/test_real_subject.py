"""Joint centres on real subjects: Plug-in Gait regressions against Vicon's own outputs,
landmark (anatomical) centres from a static with medial markers, a second vendor's landmark
pairs, and a re-taped cluster reported between the static and the dynamic trial."""
from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest
import yaml

from mocapgraph.formats.c3d_file import read_c3d
from mocapgraph.formats.trc_file import read_trc
from mocapgraph.kinematics.calibration.calibrate import CalibrationError, CalibrationWarning, calibrate, layout_markers
from mocapgraph.kinematics.layout import LayoutError, layout_path
from mocapgraph.kinematics.model import ActorModel
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.solving.solver import FrameSolver
from mocapgraph.kinematics.subject import SubjectError, parse_subject_args, read_c3d_processing, read_vsk
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.kinematics.synthetic.motion import MotionScript

PIG_REFERENCE = (("hip", "FEP"), ("knee", "FEO"), ("ankle", "TIO"))


def _quiet_calibrate(*args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CalibrationWarning)
        return calibrate(*args, **kw)


def _vs_vicon(model, res, move) -> dict[str, np.ndarray]:
    idx = {n: i for i, n in enumerate(model.joint_names)}
    out = {}
    for s, side in (("l", "L"), ("r", "R")):
        for joint, vicon in PIG_REFERENCE:
            out[f"{joint}_{s} vs {side}{vicon}"] = np.linalg.norm(
                res.joints[:, idx[f"{joint}_{s}"]] - move.model_outputs[side + vicon], axis=1)
    return out


def _table(title: str, errs: dict[str, np.ndarray]) -> None:
    print(f"\n{title}\n  {'joint vs Vicon':<18} {'median mm':>9} {'mean mm':>8} {'max mm':>8}")
    for k, e in errs.items():
        print(f"  {k:<18} {1000 * np.nanmedian(e):9.3f} {1000 * np.nanmean(e):8.3f} {1000 * np.nanmax(e):8.3f}")


@pytest.fixture
def pycgm(shared_data):
    folder = shared_data / "c3d" / "pycgm"
    static = read_c3d(folder / "Static_trial.c3d")
    move = read_c3d(folder / "Movement_trial.c3d")
    definition = SkeletonDefinition.from_layout_file("plug_in_gait")
    s = layout_markers(definition, static.labels, static.positions)
    m = layout_markers(definition, move.labels, move.positions)
    return folder, definition, s, m, move


def test_plug_in_gait_regressions_reproduce_vicon_centres(pycgm):
    folder, definition, s, m, move = pycgm
    subject = read_vsk(folder / "Test.vsk")
    assert read_c3d_processing(folder / "Static_trial.c3d").knee_width_l == pytest.approx(0.144)
    # The usual Vicon habit: the static calibrates, the walk is solved.
    model = _quiet_calibrate(definition, s, rate_hz=120.0, subject=subject,
                             centre_order=("regression", "anatomical", "functional"))
    q = model.quality
    legs = [definition.joint_index(f"{j}_{s_}") for j in ("hip", "knee", "ankle") for s_ in "lr"]
    assert all(q.method[j].startswith("regression:pig_") and q.reliable[j] for j in legs)
    assert q.inputs[definition.joint_index("knee_l")]["knee_width_m"] == pytest.approx(0.144)
    # a static alone: no functional centre is reliable (the subject stands still)
    assert not any(q.reliable[j] for j in range(len(q.method)) if j not in legs)
    res = FrameSolver(model, rate_hz=120.0).solve(m)
    errs = _vs_vicon(model, res, move)
    _table("Plug-in Gait regressions (static + Test.vsk) on the walk vs Vicon's outputs", errs)
    for k, e in errs.items():
        assert np.nanmedian(e) < 0.005, k
    assert (res.joint_quality[:, legs] == 2).all()

    # Harrington 2007 as the hip alternative: a different regression, reported beside Davis.
    lay = yaml.safe_load(layout_path("plug_in_gait").read_text())
    for limb in lay["limbs"]:
        reg = (limb.get("joint") or {}).get("regression")
        if reg and reg["method"] == "pig_hip":
            reg["method"] = "harrington_hip"
    har = SkeletonDefinition.from_layout_dict(lay, "harrington")
    model_h = _quiet_calibrate(har, s, rate_hz=120.0, subject=subject, centre_order=("regression",))
    assert model_h.quality.method[har.joint_index("hip_l")] == "regression:harrington_hip"
    eh = _vs_vicon(model_h, FrameSolver(model_h, rate_hz=120.0).solve(m), move)
    _table("Harrington 2007 hips (knees and ankles chord from them)", eh)
    assert 0.005 < np.nanmedian(eh["hip_l vs LFEP"]) < 0.04  # a different regression, the same hip


def test_plug_in_gait_without_measurements_says_what_is_missing(pycgm):
    _folder, definition, s, m, _move = pycgm
    with pytest.raises(CalibrationError, match="almost no motion.*regression centres need subject measurements"):
        calibrate(definition, s, rate_hz=120.0, centre_order=("regression",))
    with pytest.warns(CalibrationWarning) as rec:  # with the walk: functional where it moved
        model = calibrate(definition, np.concatenate([s, m]), rate_hz=120.0, centre_order=("regression", "functional"))
    assert "hip_l: regression pig_hip needs subject measurements" in " ".join(str(w.message) for w in rec)
    assert model.quality.method[definition.joint_index("hip_l")] == "sphere"
    # the ankle chord needs the ankle width: named
    sub = parse_subject_args(["LeftLegLength=877,RightLegLength=866,LeftKneeWidth=144,RightKneeWidth=139"])
    with pytest.warns(CalibrationWarning) as rec:
        model = calibrate(definition, s, rate_hz=120.0, subject=sub, centre_order=("regression",))
    assert "subject measurement left ankle width is missing" in " ".join(str(w.message) for w in rec)
    assert model.quality.method[definition.joint_index("knee_l")] == "regression:pig_knee"


def test_subject_sources_fail_clearly(tmp_path):
    with pytest.raises(SubjectError, match="no such subject file"):
        read_vsk(tmp_path / "absent.vsk")
    (tmp_path / "bad.vsk").write_text("<KinematicModel><Parameters>")
    with pytest.raises(SubjectError, match="bad.vsk: cannot read VSK"):
        read_vsk(tmp_path / "bad.vsk")
    with pytest.raises(SubjectError, match="expected key=value"):
        parse_subject_args(["LeftLegLength:877"])
    with pytest.raises(SubjectError, match="unknown measurement"):
        parse_subject_args(["LeftArmSpan=600"])
    assert parse_subject_args(["leg_length_l=900", "marker_diameter=25"]).marker_radius == pytest.approx(0.0125)


def test_opensim_static_with_medial_markers_then_walk_without(shared_data):
    folder = shared_data / "trc" / "opensim-gait2392"
    static = read_trc(folder / "subject01_static.trc")
    walk = read_trc(folder / "subject01_walk1.trc")
    definition = SkeletonDefinition.from_layout_file("opensim_gait2392")
    s = layout_markers(definition, static.labels, static.positions)
    w = layout_markers(definition, walk.labels, walk.positions, allow_missing=True)
    model = _quiet_calibrate(definition, np.concatenate([s, w]), rate_hz=60.0,
                             centre_order=("anatomical", "functional"),
                             parts=[("subject01_static.trc", len(s)), ("subject01_walk1.trc", len(w))])
    assert set(model.static_only_markers) == {f"{x}.{j}.{y}" for x in "RL" for j in ("Knee", "Ankle")
                                              for y in ("Lat", "Med")}
    idx = {n: i for i, n in enumerate(model.joint_names)}
    lab = definition.marker_labels
    res_s = FrameSolver(model, rate_hz=60.0, enforce_lengths=False).solve(s)
    print("\nOpenSim subject01: landmark centres solved in the static vs the landmark midpoints")
    for s_, side in (("l", "L"), ("r", "R")):
        for joint, pair in (("knee", "Knee"), ("ankle", "Ankle")):
            j = idx[f"{joint}_{s_}"]
            assert model.quality.method[j] == "landmarks" and model.quality.reliable[j]
            mid = 0.5 * (s[:, lab.index(f"{side}.{pair}.Lat")] + s[:, lab.index(f"{side}.{pair}.Med")])
            d = np.linalg.norm(res_s.joints[:, j] - mid, axis=1)
            print(f"  {joint}_{s_}: median {1000 * np.median(d):.2f} mm, max {1000 * d.max():.2f} mm")
            assert np.median(d) < 0.002
    # The walk has no medial or lateral knee/ankle markers at all: still solved from the clusters.
    res_w = FrameSolver(model, rate_hz=60.0, enforce_lengths=False).solve(w)
    legs = [idx[f"{j}_{s_}"] for j in ("hip", "knee", "ankle") for s_ in "lr"]
    assert (res_w.joint_quality[:, legs] > 0).all()
    print("  segment lengths over the walk (segment-wise solver, no length correction):")
    for s_ in "lr":
        for a, b in (("hip", "knee"), ("knee", "ankle")):
            L = np.linalg.norm(res_w.joints[:, idx[f"{a}_{s_}"]] - res_w.joints[:, idx[f"{b}_{s_}"]], axis=1)
            print(f"    {a}-{b}_{s_}: mean {1000 * L.mean():.1f} mm, std {1000 * L.std():.2f} mm")
            assert L.std() < 0.006


def test_qualisys_landmark_pairs_give_anatomical_centres(shared_data):
    trial = read_c3d(shared_data / "c3d" / "ezc3d-testFiles" / "Qualisys.c3d")
    definition = SkeletonDefinition.from_layout_file("qualisys")
    x = layout_markers(definition, trial.labels, trial.positions)
    model = _quiet_calibrate(definition, x, rate_hz=trial.rate_hz, centre_order=("anatomical", "functional"))
    res = FrameSolver(model, rate_hz=trial.rate_hz, enforce_lengths=False).solve(x)
    lab = definition.marker_labels
    print("\nQualisys.c3d: anatomical centres over the trial vs the per-frame landmark midpoints")
    for j, lm in enumerate(definition.joint_landmarks):
        if not lm:
            continue
        assert model.quality.method[j] == "landmarks" and model.quality.reliable[j]
        mid = 0.5 * (x[:, lm[0]] + x[:, lm[1]])
        d = np.linalg.norm(res.joints[:, j] - mid, axis=1)
        print(f"  {definition.joint_names[j]:<9} from {lab[lm[0]]} + {lab[lm[1]]}: median {1000 * np.median(d):.2f} mm, "
              f"max {1000 * d.max():.2f} mm (spread in the cluster {1000 * model.quality.residual_rms[j]:.2f} mm)")
        assert np.median(d) < 0.01  # skin markers on a walking subject move against their cluster


def test_a_retaped_cluster_is_reported_with_marker_names():
    actor = SyntheticActor("kiip_full_body", rate=60.0, seed=4, script=MotionScript(gym_block_s=1.0),
                           options=CaptureOptions(noise_mm=0.5))
    x = actor.capture(0, 600).markers.copy()
    static, dynamic = x[:120], x[120:].copy()
    definition = actor.skeleton
    parts = [("static.c3d", 120), ("rom.c3d", 480)]
    clean = _quiet_calibrate(definition, np.concatenate([static, dynamic]), rate_hz=60.0, parts=parts)
    assert not [w for w in clean.warnings if "cluster" in w]
    limb = definition.limb_index("upper_leg_l")
    own = np.flatnonzero(definition.marker_limb == limb)
    moved = definition.marker_labels[own[0]]
    # re-taped: the marker sits 9 mm further along its cluster's first edge in the dynamic trial
    edge = dynamic[:, own[1]] - dynamic[:, own[0]]
    dynamic[:, own[0]] -= 0.009 * edge / np.linalg.norm(edge, axis=-1, keepdims=True)
    with pytest.warns(CalibrationWarning, match="cluster upper_leg_l changed"):
        model = calibrate(definition, np.concatenate([static, dynamic]), rate_hz=60.0, parts=parts)
    msgs = [w for w in model.warnings if "cluster" in w]
    print("\n" + "\n".join(msgs))
    first = definition.marker_labels[own[1]]
    hit = [w for w in msgs if f"{moved}-{first}" in w or f"{first}-{moved}" in w]
    assert hit and "+9.0 mm" in hit[0] and "static.c3d and rom.c3d" in hit[0]
    assert all(moved in w for w in msgs)  # only pairs with the moved marker


@pytest.mark.parametrize("joint, problem", [
    ({"name": "knee_x", "type": "hinge", "landmarks": ["A"]}, "landmarks must be a list of two"),
    ({"name": "knee_x", "type": "hinge", "landmarks": ["A", "Z"]}, "landmark `Z` is not a marker of"),
    ({"name": "knee_x", "type": "hinge", "regression": {"method": "magic"}}, "regression needs `method:`"),
    ({"name": "knee_x", "type": "hinge", "regression": {"method": "pig_knee", "side": "left",
                                                         "markers": {"wand": "A"}}}, "needs markers for wand, lateral"),
    ({"name": "knee_x", "type": "hinge", "centre": 1}, "unknown key"),
])
def test_bad_landmark_and_regression_keys_are_one_line_errors(joint, problem):
    lay = {"name": "t", "limbs": [{"name": "a", "markers": ["A", "B", "C"]},
                                  {"name": "b", "parent": "a", "joint": joint, "markers": ["D", "E", "F"]}]}
    with pytest.raises(LayoutError, match=problem) as exc:
        SkeletonDefinition.from_layout_dict(copy.deepcopy(lay), "t.yaml")
    assert "\n" not in str(exc.value)


def test_model_file_keeps_methods_inputs_and_static_only_markers(tmp_path, shared_data):
    from mocapgraph.kinematics.model import load_model, save_model
    from mocapgraph.adapters.model_messages import model_from_message, model_to_message

    folder = shared_data / "trc" / "opensim-gait2392"
    static = read_trc(folder / "subject01_static.trc")
    walk = read_trc(folder / "subject01_walk1.trc")
    definition = SkeletonDefinition.from_layout_file("opensim_gait2392")
    s = layout_markers(definition, static.labels, static.positions)
    w = layout_markers(definition, walk.labels, walk.positions, allow_missing=True)
    model = _quiet_calibrate(definition, np.concatenate([s, w]), rate_hz=60.0, centre_order=("anatomical", "functional"),
                             parts=[("s", len(s)), ("w", len(w))])
    save_model(model, tmp_path / "m.json")
    # A stream without the static-only landmarks is accepted (they are always missing); one that
    # lacks any other model marker is still refused.
    from mocapgraph.adapters.model_messages import ModelMismatchError, marker_index

    where = marker_index(model, "opensim_gait2392", walk.labels)
    absent = {model.marker_labels[m] for m in np.flatnonzero(where < 0)}
    assert absent == set(model.static_only_markers)
    with pytest.raises(ModelMismatchError, match="R.Heel"):
        marker_index(model, "opensim_gait2392", [l for l in walk.labels if l != "R.Heel"])
    for back in (load_model(tmp_path / "m.json"), model_from_message(model_to_message(model))):
        assert isinstance(back, ActorModel)
        assert back.static_only_markers == model.static_only_markers
        assert back.quality.method == model.quality.method
        assert back.quality.inputs[1]["landmarks"] == ["R.Knee.Lat", "R.Knee.Med"]
