"""The one-frame path (retarget_live) gives the batched path's output on real clips, frame by frame."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.kinect_csv import read_kinect_csv
from mocapgraph.formats.mapping_file import load_mapping
from mocapgraph.kinematics.character import standard_20
from mocapgraph.kinematics.retarget import RetargetOptions, Retargeter
from mocapgraph.kinematics.retarget_mapping import derive_mapping
from mocapgraph.kinematics.retarget_source import kinect_source

from retarget_support import bvh_source

FIELDS = ("local_rotations", "root_positions", "joint_positions", "joint_quality", "contact")


def _compare(ch, mapping, src, opts, pts, pok, rot, t):
    batch = Retargeter(ch, mapping, src, opts, live=False).process(pts, pok, rot, None, t)
    live = Retargeter(ch, mapping, src, opts)
    assert live._live is not None
    frames = [live.process(pts[f:f + 1], None if pok is None else pok[f:f + 1],
                           None if rot is None else rot[f:f + 1], None, t[f:f + 1]) for f in range(len(pts))]
    worst = {}
    for k in FIELDS:
        got = np.concatenate([getattr(r, k) for r in frames]).astype(float)
        worst[k] = float(np.abs(got - getattr(batch, k).astype(float)).max())
    return batch, worst


@pytest.mark.parametrize("planting", [False, True])
def test_live_equals_batch_cmu_onto_mixamo_with_gaps(shared_data, planting):
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    n = 400
    pts, rot = trial.positions[:n].copy(), trial.orientations[:n].copy()
    # gaps: a wrist point and a forearm rotation vanish for a while, a bad quaternion once
    pts[100:140, 20] = np.nan
    rot[150:170, 18] = np.nan
    rot[200, 5] *= 1.5
    mix = load_character("mixamo")
    opts = RetargetOptions(foot_planting=planting)
    batch, worst = _compare(mix, derive_mapping(mix, src), src, opts, pts, None, rot, np.arange(n) / motion.rate_hz)
    print(f"\nCMU 131_01 onto Mixamo, planting {planting}: live - batch max " +
          ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    assert (batch.joint_quality < 2).any()          # the gaps did reach the comparison
    assert batch.contact.any() == planting          # and the plants, with planting on
    for k, v in worst.items():
        assert v < 1e-12 if k != "joint_quality" and k != "contact" else v == 0, (k, v)


def test_live_equals_batch_kinect_positions_only_with_dependencies(shared_data):
    trial = read_kinect_csv(shared_data / "kinect2" / "Ges03_drawlines.csv", ground="feet")
    src = kinect_source(trial.names, trial.parents)
    n = 300
    pok = trial.tracking_state[:n] == 2
    ch = standard_20(1.75)
    mapping = load_mapping("kinect_v2_standard_20")
    # Claro's dependency form, source rotations multiplied after Q_k (two levels on one joint)
    deps = {"ShoulderCenter": ("SpineMid", "SpineBase"), "Head": ("SpineShoulder",)}
    mapping = replace(mapping, joints=tuple(replace(e, D=deps[e.joint]) if e.joint in deps else e
                                            for e in mapping.joints))
    batch, worst = _compare(ch, mapping, src, RetargetOptions(), trial.positions[:n], pok, None, np.arange(n) / 30.0)
    print("\nKinect v2 onto standard_20: live - batch max " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    assert not pok.all()
    for k, v in worst.items():
        assert v < 1e-12 if k not in ("joint_quality", "contact") else v == 0, (k, v)


def test_the_nodes_point_layout_is_optical_points():
    """The node's precomputed per-frame layout gives optical_points' pelvis (mean of the hips) and
    masks from the joint quality, NaN joints included."""
    from mocapgraph.kinematics.retarget_source import OpticalFrames, optical_points
    names = ["pelvis_top", "hip_l", "knee_l", "hip_r", "knee_r"]
    rng = np.random.default_rng(3)
    p = rng.normal(size=(5, 3))
    q = np.array([2, 2, 1, 0, 2], np.int8)
    p[3] = np.nan
    pts, ok = OpticalFrames(names).frame(p, q)
    want = optical_points(p[None], names)
    np.testing.assert_array_equal(np.isnan(pts), np.isnan(want))
    np.testing.assert_allclose(pts[np.isfinite(want)], want[np.isfinite(want)], rtol=0, atol=0)
    assert ok.tolist() == [[True, True, True, False, True, False]]
