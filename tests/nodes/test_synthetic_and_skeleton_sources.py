"""The synthetic actor node against the library capture (markers and exact ground truth), and
the skeleton sources (Kinect CSV, BVH) against their file readers."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.formats import KINECT_V1_JOINTS, KINECT_V1_PARENTS, bvh_to_skeleton, read_bvh, read_kinect_csv
from mocapgraph.kinematics.model import marker_fingerprint
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
from mocapgraph.messages import QUALITY_GOOD


@pytest.mark.parametrize("precompute_mb", [64.0, 0.0])   # whole session at start / worker thread
def test_synthetic_actor_node_sends_the_library_capture_and_exact_ground_truth(run_node, precompute_mb) -> None:
    opts = dict(noise_mm=2.0, wobble_mm=3.0, dropout_rate_hz=0.5, shadow_rate_hz=0.5, swap_rate_hz=0.3)
    n = run_node("synthetic_actor", {"layout": "plug_in_gait", "rate_hz": 200.0, "seed": 7, "duration_s": 1.5,
                                     "loop": False, "rate_scale": 0.0, "precompute_mb": precompute_mb, **opts})
    assert n.wait_exit(10) == 0
    ref = SyntheticActor("plug_in_gait", rate=200.0, seed=7, duration_s=1.5,
                         options=CaptureOptions(**opts)).capture()
    frames = n.messages("markers")
    truth = n.messages("ground_truth")
    assert len(frames) == len(truth) == ref.n_frames == 300
    np.testing.assert_array_equal(np.array([f.positions for f in frames]), ref.markers)
    np.testing.assert_array_equal(np.array([f.valid for f in frames]), ref.valid)
    assert not ref.valid.all()  # the options really hid markers
    np.testing.assert_array_equal(np.array([t.joint_positions for t in truth]), ref.joint_centres)
    np.testing.assert_array_equal(np.array([t.limb_orientations for t in truth]), ref.limb_quat)
    assert all((t.joint_quality == QUALITY_GOOD).all() for t in truth)
    owner = np.asarray(ref.skeleton.marker_limb)
    visible = np.array([[v[owner == limb].sum() for limb in range(ref.skeleton.n_limbs)] for v in ref.valid[:20]])
    np.testing.assert_array_equal(np.array([t.limb_visible_markers for t in truth[:20]]), visible)
    recs = n.records("markers")
    np.testing.assert_allclose(np.diff([r.env.capture_ns for r in recs]), 5e6, atol=1)
    assert [r.env.capture_ns for r in recs] == [r.env.capture_ns for r in n.records("ground_truth")]
    model = n.messages("ground_truth_model")
    assert len(model) == 1
    m = model[0]
    assert m.marker_labels == list(ref.skeleton.marker_labels)
    assert m.fingerprint == marker_fingerprint(m.marker_labels)
    np.testing.assert_array_equal(m.base_markers, ref.base_markers)
    np.testing.assert_array_equal(m.joint_offsets, ref.joint_offsets)
    np.testing.assert_array_equal(m.base_joints, ref.base_joint_centres)
    # Bone lengths: joint to parent joint in the base pose, measured independently here.
    j = int(np.flatnonzero(m.joint_parent >= 0)[0])
    assert m.bone_lengths[j] == pytest.approx(np.linalg.norm(ref.base_joint_centres[j]
                                                             - ref.base_joint_centres[m.joint_parent[j]]))
    assert np.isnan(m.bone_lengths[m.joint_parent < 0]).all()
    assert n.messages("marker_layout")[0].labels == m.marker_labels


def test_synthetic_actor_paces_frames_in_real_time(run_node) -> None:
    n = run_node("synthetic_actor", {"layout": "one_arm", "rate_hz": 100.0})
    recs = n.wait_for(lambda: n.records("markers")[:50] if len(n.records("markers")) >= 50 else None,
                      what="50 frames")
    assert [r.msg.frame_number for r in recs] == list(range(50))
    pub = np.array([r.env.publish_ns for r in recs]) / 1e9
    assert 0.45 < pub[-1] - pub[0] < 0.6                                 # 49 periods of 10 ms


@pytest.mark.parametrize("precompute_mb", [64.0, 0.0])
def test_synthetic_actor_loops_seamlessly_with_continuing_numbers(run_node, precompute_mb) -> None:
    rate = 40.0
    n = run_node("synthetic_actor", {"layout": "one_arm", "rate_hz": rate, "rate_scale": 0.0, "loop": True,
                                     "precompute_mb": precompute_mb})
    per_pass = int(round(SyntheticActor("one_arm", rate=rate).n_frames))
    recs = n.wait_for(lambda: n.records("markers")[: per_pass + 40] if len(n.records("markers")) >= per_pass + 40
                      else None, what="a pass and a bit")
    assert [r.msg.frame_number for r in recs] == list(range(per_pass + 40))   # numbering continues
    cap = np.diff([r.env.capture_ns for r in recs])
    np.testing.assert_allclose(cap, 1e9 / rate, atol=1)
    pos = np.array([r.msg.positions for r in recs])
    np.testing.assert_array_equal(pos[per_pass:], pos[:40])                   # the pass repeats
    # The session ends in the base pose where it starts: no jump at the seam.
    step = np.linalg.norm(np.diff(pos, axis=0), axis=2).max(axis=1)
    seam = per_pass - 1
    assert step.max() > 0.02 and step[seam] <= 1.5 * step[seam - 4:seam].max() + 1e-6


@pytest.mark.parametrize("precompute_mb", [64.0, 0.0])
def test_synthetic_actor_starts_later_in_the_session_and_loops_from_its_beginning(run_node, precompute_mb) -> None:
    rate, start_s = 40.0, 17.0   # the default script's performance
    n = run_node("synthetic_actor", {"layout": "one_arm", "rate_hz": rate, "rate_scale": 0.0, "loop": True,
                                     "start_s": start_s, "precompute_mb": precompute_mb})
    ref = SyntheticActor("one_arm", rate=rate).capture()
    start = int(start_s * rate)
    assert ref.phases["performance"][0] == start
    rest = ref.n_frames - start
    recs = n.wait_for(lambda: n.records("markers")[: rest + 40] if len(n.records("markers")) >= rest + 40
                      else None, what="the rest of a pass and a bit")
    # the session's own frame numbers from the start on, counting on through the loop
    assert [r.msg.frame_number for r in recs] == list(range(start, start + rest + 40))
    pos = np.array([r.msg.positions for r in recs])
    np.testing.assert_array_equal(pos[:rest], ref.markers[start:])
    np.testing.assert_array_equal(pos[rest:], ref.markers[:40])                 # the loop starts at 0 s
    truth = n.wait_for(lambda: n.messages("ground_truth")[: rest + 40]
                       if len(n.messages("ground_truth")) >= rest + 40 else None, what="ground truth")
    assert [t.frame_number for t in truth] == list(range(start, start + rest + 40))
    np.testing.assert_array_equal(np.array([t.joint_positions for t in truth[:rest]]), ref.joint_centres[start:])
    np.testing.assert_allclose(np.diff([r.env.capture_ns for r in recs]), 1e9 / rate, atol=1)
    assert "from 17 s" in n.messages("reader_status")[-1].detail


def test_synthetic_actor_script_timing(run_node) -> None:
    n = run_node("synthetic_actor", {"layout": "one_arm", "rate_hz": 50.0, "rate_scale": 0.0, "loop": False,
                                     "script": {"base_s": 0.5, "gym_block_s": 1.0, "walk_s": 1.0, "reach_s": 0.5,
                                                "turn_s": 0.5, "kick_s": 0.5}})
    assert n.wait_exit(10) == 0
    assert len(n.messages("markers")) == 50 * (0.5 + 4 * 1.0 + 2 * 1.0 + 0.5 + 2 * 0.5 + 0.5)


@pytest.mark.parametrize("params, fault", [({"layout": "no_such_layout"}, "no_such_layout"),
                                           ({"script": {"walk_speedd": 2}}, "walk_speedd"),
                                           ({"start_s": 40.0}, "start_s 40 s is not inside the session")])
def test_synthetic_actor_bad_settings_are_clear_errors(run_node, params, fault) -> None:
    n = run_node("synthetic_actor", params)
    assert n.wait_exit(10) == 1
    assert fault in n.messages("reader_status")[-1].detail


def test_kinect_replay_keeps_recorded_timing_tracking_and_device_pose(run_node, shared_data) -> None:
    path = shared_data / "kinect2" / "Ges01_wavehand.csv"
    n = run_node("kinect_reader", {"file": str(path), "device": "kinect_front", "rate_scale": 4.0,
                                   "version": "v2"})
    assert n.wait_exit(15) == 0
    ref = read_kinect_csv(path)
    info = n.messages("skeleton_info")[0]
    assert info.source == "kinect_v2" and len(info.joint_names) == 25 and info.joint_names[0] == "SpineBase"
    assert "kinect_front" in info.units_note
    recs = n.records("skeleton_pose")
    assert len(recs) == ref.n_frames
    got = np.array([r.msg.joint_positions for r in recs])
    np.testing.assert_allclose(got, ref.positions + [2.5, 0.0, 0.0], atol=1e-12)   # sensor 2.5 m forward
    np.testing.assert_array_equal(np.array([r.msg.tracking_state for r in recs]), ref.tracking_state)
    assert np.isnan(got[ref.tracking_state == 0]).all()
    assert (ref.tracking_state == 1).any() and np.isfinite(got[ref.tracking_state == 1]).all()
    # Stamps follow the recording's own (uneven) time stamps, dropped frames included.
    cap = np.array([r.env.capture_ns for r in recs])
    np.testing.assert_array_equal(cap - cap[0], ref.timestamps_ns - ref.timestamps_ns[0])
    rest = info.rest_offsets
    neck = info.joint_names.index("Neck")
    assert 0.03 < np.linalg.norm(rest[neck]) < 0.2 and rest[neck][2] > 0   # neck sits above its parent
    # the root's offset is its rest position, placed in the room like the joints (sensor 2.5 m forward)
    np.testing.assert_allclose(rest[0], np.nanmedian(ref.positions[:, 0], axis=0) + [2.5, 0.0, 0.0])


def test_kinect_v1_recording_uses_the_20_joint_definition(run_node, shared_data, tmp_path) -> None:
    # A v1 recording: the 20 joints v1 shares with v2 (v2's first 20), same line format.
    lines = (shared_data / "kinect2" / "Ges01_wavehand.csv").read_text().splitlines()[:40]
    v1 = tmp_path / "v1.csv"
    v1.write_text("\n".join(",".join(line.rstrip(",").split(",")[:1 + 20 * 4]) for line in lines) + "\n")
    n = run_node("kinect_reader", {"file": str(v1), "version": "v1", "rate_scale": 0.0})
    assert n.wait_exit(10) == 0
    info = n.messages("skeleton_info")[0]
    assert info.source == "kinect_v1" and info.joint_names == list(KINECT_V1_JOINTS)
    np.testing.assert_array_equal(info.joint_parent, KINECT_V1_PARENTS)
    ref = read_kinect_csv(v1)
    got = np.array([m.joint_positions for m in n.messages("skeleton_pose")])
    np.testing.assert_array_equal(got, ref.positions)
    assert got.shape == (40, 20, 3)


def test_kinect_version_mismatch_is_a_clear_error(run_node, shared_data) -> None:
    n = run_node("kinect_reader", {"file": str(shared_data / "kinect2" / "Ges01_wavehand.csv"), "version": "v1"})
    assert n.wait_exit(10) == 1
    assert "Kinect v2" in n.messages("reader_status")[-1].detail


@pytest.mark.parametrize("rel", ["bvh/cmu/131_01.bvh", "bvh/mixamo/test_freebvh.bvh"])
def test_bvh_player_sends_forward_kinematics_of_any_hierarchy(run_node, shared_data, rel) -> None:
    path = shared_data / rel
    n = run_node("bvh_player", {"file": str(path), "rate_scale": 0.0, "end_frame": 59})
    assert n.wait_exit(10) == 0
    motion = read_bvh(path)
    ref = bvh_to_skeleton(motion)
    info = n.messages("skeleton_info")[0]
    assert info.source == "bvh" and info.joint_names == ref.names
    np.testing.assert_array_equal(info.joint_parent, ref.parents)
    recs = n.records("skeleton_pose")
    assert [r.msg.frame_number for r in recs] == list(range(60))
    np.testing.assert_array_equal(np.array([r.msg.joint_positions for r in recs]), ref.positions[:60])
    np.testing.assert_array_equal(np.array([r.msg.joint_orientations for r in recs]), ref.orientations[:60])
    cap = np.array([r.env.capture_ns for r in recs])
    np.testing.assert_allclose(np.diff(cap), 1e9 / motion.rate_hz, atol=1)
    # Rest offsets are the BVH offsets in metres: the rest pose rebuilt from them matches FK at rest.
    rest = motion.rest_positions()[[motion.names.index(nm) for nm in ref.names]]
    rebuilt = np.zeros_like(rest)
    for j in ref.topological_order:
        p = ref.parents[j]
        rebuilt[j] = info.rest_offsets[j] + (rebuilt[p] if p >= 0 else 0.0)
    np.testing.assert_allclose(rebuilt, rest, atol=1e-9)
