"""Kinect v2 recordings onto standard_20 with the shipped mapping file (Claro's A, R, D form)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.formats.mapping_file import load_mapping
from mocapgraph.kinematics.character import standard_20
from mocapgraph.kinematics.retarget import RetargetOptions, Retargeter
from mocapgraph.kinematics.retarget_source import kinect_source

from retarget_support import angle_deg, mapped_bones

RECORDINGS = ["Ges01_wavehand", "Ges02_balancinghands", "Ges03_drawlines", "Ges04_comehere", "Ges05_demopoint"]


def _run(path):
    trial = read_kinect_csv(path, ground="feet")
    src = kinect_source(trial.names, trial.parents)
    ch = standard_20(1.75)
    mapping = load_mapping("kinect_v2_standard_20")
    rt = Retargeter(ch, mapping, src, RetargetOptions())
    res = rt.process(trial.positions, trial.tracking_state == 2)
    return trial, src, ch, mapping, res


@pytest.mark.parametrize("name", RECORDINGS)
def test_kinect_v2_onto_standard_20_follows_the_tracked_bones(shared_data, name):
    trial, src, ch, mapping, res = _run(shared_data / "kinect2" / f"{name}.csv")
    assert np.isfinite(res.local_rotations).all() and np.isfinite(res.joint_positions).all()
    lines = []
    for j, k, a, b in mapped_bones(ch, mapping, src):
        ok = (trial.tracking_state[:, a] == 2) & (trial.tracking_state[:, b] == 2)
        ang = angle_deg(res.joint_positions[ok, k] - res.joint_positions[ok, j],
                        trial.positions[ok, b] - trial.positions[ok, a])
        girdle = len(ch.children(j)) > 1 and ch.joint_names[k] not in ("Spine",)
        lines.append(f"  {ch.joint_names[j]:>14} -> {ch.joint_names[k]:<14} mean {ang.mean():5.1f} max {ang.max():5.1f}"
                     + ("  (rigid girdle of standard_20: rest-shape difference)" if girdle else ""))
        if girdle:
            continue   # standard_20's pelvis and shoulder line are rigid; the Kinect's are not
        assert ang.max() < 10.0, (ch.joint_names[j], ch.joint_names[k], ang.max())
    print(f"\n{name}: tracked bones vs the Kinect's (deg)\n" + "\n".join(lines))


def test_dependency_chain_spine_base_spine_shoulder_centre(shared_data):
    """The character's shoulder centre turns, through HipCenter · Spine · ShoulderCenter, exactly as the
    Kinect's spine shoulder does: checked with scipy's own two-vector alignment of the Kinect points."""
    trial, src, ch, mapping, res = _run(shared_data / "kinect2" / "Ges03_drawlines.csv")
    n = trial.names.index
    rest = src.rest_points
    ok = (trial.tracking_state[:, [n("SpineShoulder"), n("Neck"), n("ShoulderLeft"), n("ShoulderRight")]] == 2).all(1)
    frames = np.flatnonzero(ok)[::5]
    assert len(frames) > 20
    chain = [ch.index("HipCenter"), ch.index("Spine"), ch.index("ShoulderCenter")]
    worst = 0.0
    for f in frames:
        p = trial.positions[f]
        ref, _ = Rotation.align_vectors(
            [p[n("Neck")] - p[n("SpineShoulder")], p[n("ShoulderLeft")] - p[n("ShoulderRight")]],
            [rest[n("Neck")] - rest[n("SpineShoulder")], rest[n("ShoulderLeft")] - rest[n("ShoulderRight")]],
            weights=[np.inf, 1.0])
        mapped = mapping.entry("ShoulderCenter")
        r_inv = Rotation.from_quat(mapped.R, scalar_first=True).inv()
        composed = Rotation.identity()
        for j in chain:   # standard_20 has identity rest rotations: world = product of locals
            composed = composed * Rotation.from_quat(res.local_rotations[f, j], scalar_first=True)
        worst = max(worst, ((ref * r_inv).inv() * composed).magnitude())
    print(f"\nShoulderCenter world rotation vs scipy's alignment of the Kinect spine shoulder: max {np.degrees(worst):.2e} deg")
    assert worst < 1e-6


def test_the_shipped_kinect_mapping_is_claros_form():
    m = load_mapping("kinect_v2_standard_20")
    assert m.source == "kinect_v2" and m.character == "standard_20"
    e = m.entry("ElbowLeft")
    assert e.rotation == "ElbowLeft" and e.R.shape == (4,) and e.A.shape == (4,)
    assert {x.joint for x in m.joints} >= {"HipCenter", "Spine", "ShoulderCenter", "ShoulderLeft", "KneeRight"}


def test_the_pelvis_line_error_is_standard_20s_rest_shape(shared_data):
    """Why standard_20's pelvis lines miss the Kinect's by ~34 deg: a constant rest-shape offset, not a
    tracking fault. In the Kinect's own pelvis frame (up: SpineBase->SpineMid, left: the hip line)
    its hip joints sit ~3.4 cm in front of SpineBase and level with it, standard_20's 3.5 cm below
    and in line: the angle between those two offsets is the retargeted error, frame by frame, to
    within 1 deg, and it hardly changes over the recording (a shape no rotation of a rigid pelvis
    can match; a character whose pelvis had the Kinect's shape would follow)."""
    trial, src, ch, mapping, res = _run(shared_data / "kinect2" / "Ges03_drawlines.csv")
    n = trial.names.index
    P = trial.positions
    ok = (trial.tracking_state[:, [n("SpineBase"), n("SpineMid"), n("HipLeft"), n("HipRight")]] == 2).all(1)
    up = P[ok, n("SpineMid")] - P[ok, n("SpineBase")]
    up /= np.linalg.norm(up, axis=1, keepdims=True)
    left = P[ok, n("HipLeft")] - P[ok, n("HipRight")]
    left -= np.sum(left * up, 1, keepdims=True) * up
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    frame = np.stack([np.cross(left, up), left, up], axis=1)                  # rows: forward, left, up
    hip_k = np.einsum("fij,fj->fi", frame, P[ok, n("HipLeft")] - P[ok, n("SpineBase")])
    hip_c = ch.rest_offsets[ch.index("HipLeft")]
    expected = angle_deg(hip_k, np.broadcast_to(hip_c, hip_k.shape))
    j, k = ch.index("HipCenter"), ch.index("HipLeft")
    got = angle_deg(res.joint_positions[ok, k] - res.joint_positions[ok, j], P[ok, n("HipLeft")] - P[ok, n("SpineBase")])
    print(f"\nKinect v2 hip joint in its pelvis frame (fwd, left, up), mean: {np.round(hip_k.mean(0), 3)} m; "
          f"standard_20's: {np.round(hip_c, 3)} m;\n  angle between them {expected.mean():.1f} deg (std {expected.std():.1f}), "
          f"retargeted pelvis-line error {got.mean():.1f} deg (std {got.std():.1f})")
    assert np.abs(got - expected).max() < 1.0
    assert expected.std() < 3.0 and expected.mean() > 25.0
    assert hip_k[:, 0].mean() > 0.02 and abs(hip_k[:, 2].mean()) < 0.015      # forward of and level with SpineBase
