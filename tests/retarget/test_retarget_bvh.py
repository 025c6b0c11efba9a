"""Retargeting BVH skeletons: CMU onto itself exactly, CMU onto Mixamo with the automatic mapping."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats.bvh_file import BVH_TO_WORLD, read_bvh
from mocapgraph.formats.character_file import character_from_bvh, load_character
from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
from mocapgraph.retarget.mapping import derive_mapping

from retarget_support import angle_deg, bvh_source, mapped_bones


def _bvh_local_rotations(motion) -> np.ndarray:
    """Each joint's local rotation straight from its Euler channels (scipy), in world axes."""
    T, J = motion.n_frames, motion.n_joints
    out = np.tile([1.0, 0, 0, 0], (T, J, 1))
    orders = motion.rotation_orders()
    for j in range(J):
        if not orders[j]:
            continue
        cols = [motion.channel_start[j] + k for k, c in enumerate(motion.channels[j]) if c.endswith("rotation")]
        m = Rotation.from_euler(orders[j], motion.values[:, cols], degrees=True).as_matrix()
        out[:, j] = Rotation.from_matrix(BVH_TO_WORLD @ m @ BVH_TO_WORLD.T).as_quat(scalar_first=True)
    return out


def test_cmu_onto_its_own_skeleton_gives_everything_back(shared_data):
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    ch = load_character(shared_data / "bvh/cmu/131_01.bvh")        # the file's own HIERARCHY
    rt = Retargeter(ch, derive_mapping(ch, src), src, RetargetOptions())
    res = rt.process(trial.positions, None, trial.orientations)
    truth = _bvh_local_rotations(motion)
    ang = (Rotation.from_quat(res.local_rotations.reshape(-1, 4), scalar_first=True).inv()
           * Rotation.from_quat(truth.reshape(-1, 4), scalar_first=True)).magnitude()
    pos_err = np.abs(res.joint_positions - trial.positions).max()
    print(f"\nCMU 131_01 onto itself ({motion.n_frames} frames, {ch.n_joints} joints): local rotations max "
          f"{ang.max():.2e} rad, joint positions max {pos_err:.2e} m")
    assert ang.max() < 1e-6
    assert pos_err < 1e-6
    assert (res.joint_quality == 2).all()


def test_cmu_onto_mixamo_follows_every_mapped_bone_without_flips(shared_data):
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    mix = load_character("mixamo")
    assert "LeftHandIndex1" in mix.joint_names and not any(":" in n for n in mix.joint_names)
    mapping = derive_mapping(mix, src)
    rt = Retargeter(mix, mapping, src, RetargetOptions())
    res = rt.process(trial.positions, None, trial.orientations)
    assert np.isfinite(res.local_rotations).all()
    bones = mapped_bones(mix, mapping, src)
    assert len(bones) >= 17
    rows = []
    for j, k, a, b in bones:
        ang = angle_deg(res.joint_positions[:, k] - res.joint_positions[:, j], trial.positions[:, b] - trial.positions[:, a])
        # a joint with several mapped bones (the pelvis) cannot match two V shapes of different
        # opening; its bones must keep the rest-pose difference, not drift from it
        rest_ang = angle_deg(rt.plan.rest_pos[k] - rt.plan.rest_pos[j], src.rest_points[b] - src.rest_points[a])
        several = sum(1 for x in bones if x[0] == j) > 1
        rows.append((mix.joint_names[j], mix.joint_names[k], ang.max(), several))
        if several:
            assert np.abs(ang - ang[0]).max() < 5.0, (mix.joint_names[j], mix.joint_names[k])
        else:
            assert ang.max() < 5.0, (mix.joint_names[j], mix.joint_names[k], ang.max(), rest_ang)
    print("\nCMU -> Mixamo, worst angle to the source bone over 131_01 (deg):")
    for r in sorted(rows, key=lambda r: -r[2]):
        print(f"  {r[0]:>14} -> {r[1]:<14} {r[2]:6.2f}{'  (pelvis V, rest-shape difference)' if r[3] else ''}")
    # no flips: every mapped bone turns between frames no more than its source bone (plus 1 deg)
    worst = 0.0
    for j, k, a, b in bones:
        cb = res.joint_positions[:, k] - res.joint_positions[:, j]
        sb = trial.positions[:, b] - trial.positions[:, a]
        excess = angle_deg(cb[1:], cb[:-1]) - angle_deg(sb[1:], sb[:-1])
        worst = max(worst, float(excess.max()))
    print(f"largest frame-to-frame turn of a character bone beyond its source bone's: {worst:.3f} deg")
    assert worst < 1.0


def _world(ch, res) -> np.ndarray:
    _, w = ch.forward_kinematics(res.local_rotations, res.root_positions)
    return w


def test_character_from_bvh_strips_the_mixamo_prefix_and_keeps_every_joint(shared_data):
    motion = read_bvh(shared_data / "bvh/mixamo/test_freebvh.bvh")
    ch = character_from_bvh(motion)
    assert ch.n_joints == motion.n_joints
    assert ch.joint_names[0] == "Hips" and "LeftHandThumb1" in ch.joint_names
    shipped = load_character("mixamo")
    assert shipped.joint_names == ch.joint_names
    np.testing.assert_allclose(shipped.rest_offsets, ch.rest_offsets, atol=1e-8)
    # the character's rest pose is the BVH rest pose in world axes
    np.testing.assert_allclose(ch.rest_pose()[0], motion.rest_positions(), atol=1e-9)


def test_missing_and_broken_source_joints_are_held_and_flagged(shared_data):
    """NaN joints, a non-unit quaternion on the stream, a joint never seen: never NaN out, flags tell."""
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    ch = load_character("mixamo")
    m = derive_mapping(ch, src)
    q = trial.orientations[:200].copy()
    p = trial.positions[:200].copy()
    elbow = src.rotation("LeftElbow")
    q[50:80, elbow] = np.nan                       # lost for 30 frames
    q[90, elbow] *= 1.7                            # a corrupt (non-unit) quaternion
    q[:, src.rotation("RightWrist")] = np.nan      # never seen at all
    p[120:125] = np.nan                            # a whole frame of positions gone
    ref = Retargeter(ch, m, src, RetargetOptions()).process(trial.positions[:200], None, trial.orientations[:200])
    res = Retargeter(ch, m, src, RetargetOptions()).process(p, None, q)
    assert np.isfinite(res.local_rotations).all() and np.isfinite(res.joint_positions).all()
    fore, hand = ch.index("LeftForeArm"), ch.index("LeftHand")
    assert (res.joint_quality[50:80, fore] == 1).all() and (res.joint_quality[50:80, hand] == 1).all()
    assert res.joint_quality[90, fore] == 1 and res.joint_quality[91, fore] == 2
    assert (res.joint_quality[:, ch.index("RightHand")] == 0).all()         # never seen: rest pose, missing
    assert (res.joint_quality[120:125, ch.root] == 1).all()                  # the root held too
    np.testing.assert_allclose(res.root_positions[120:125], np.repeat(res.root_positions[119:120], 5, 0), atol=1e-12)
    ok = np.ones(200, bool)
    ok[50:125] = False
    assert np.abs(res.joint_positions[ok][:, [ch.index("Spine2")]] - ref.joint_positions[ok][:, [ch.index("Spine2")]]).max() < 1e-9


def test_cmu_walk_onto_mixamo_detects_foot_contact(shared_data):
    """CMU 131_01 (a walk, 4.5 m in 8.3 s) onto Mixamo with foot planting: each foot is in contact
    through its stances. Reference, from the source alone: the source ankle within 3 cm of its
    lowest and slower than 0.3 m/s (about 40 % of the frames per foot). Skating is the planted
    ankle's horizontal step beyond the source ankle's own step scaled by the root ratio (a heel
    roll moves the source's ankle too, and that is no skating). Measured on this clip: contact
    43 % / 38 % of the frames, 91 % / 91 % agreeing with the source's stance, skating at most 0.55 mm
    a frame (1.4 mm with planting off). (Before, the CMU rest pose's level feet put the character's
    ankles 15 cm up and no contact was ever detected.)"""
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    mix = load_character("mixamo")
    rt = Retargeter(mix, derive_mapping(mix, src), src, RetargetOptions(foot_planting=True))
    res = rt.process(trial.positions, None, trial.orientations, None, np.arange(motion.n_frames) / motion.rate_hz)
    legs = rt.plan.legs
    lines = []
    for i, name in enumerate(("LeftAnkle", "RightAnkle")):
        a = trial.positions[:, src.point(name)]
        v = np.r_[0.0, np.linalg.norm(np.diff(a[:, :2], axis=0), axis=1)] * motion.rate_hz
        stance = (a[:, 2] < a[:, 2].min() + 0.03) & (v < 0.3)
        c = res.contact[:, i]
        ankle = res.joint_positions[:, legs["ankle"][i]]
        held = c[1:] & c[:-1]
        own = np.diff(rt.plan.ratio * a[:, :2], axis=0)           # the source's own step, scaled
        skate = np.linalg.norm(np.diff(ankle[:, :2], axis=0) - own, axis=1)[held]
        lines.append(f"  {name}: contact {100 * c.mean():.0f} % of frames (source stance {100 * stance.mean():.0f} %), "
                     f"agreeing {100 * (c == stance).mean():.0f} %, skating max {1e3 * skate.max():.2f} mm/frame")
        assert 0.25 < c.mean() < 0.6, (name, c.mean())
        assert (c == stance).mean() > 0.8, name
        assert skate.max() < 1e-3
        assert ankle[:, 2].min() > legs["rest_h"][i] - 5e-3       # above the floor
    print("\nCMU 131_01 onto Mixamo, foot planting:\n" + "\n".join(lines))


def _largest_steps(p: np.ndarray) -> np.ndarray:
    """Each joint's largest per-frame step [J], m, of positions [F, J, 3]."""
    return np.linalg.norm(np.diff(p, axis=0), axis=-1).max(0)


def test_planting_changes_nothing_but_skating_on_cmu(shared_data):
    """Issue 27 item 4. CMU 131_01 onto its own skeleton with planting on: wherever a source foot
    moves less than 2 mm a frame its leg stays within 1 cm of the source (measured: 0.0 mm, where
    holding the plant still moved a knee 9.8 cm), and no joint steps more than 20 % beyond the
    source's largest step. Onto Mixamo: what planting changes beside the skating it removes, the
    step bound against the same retarget without planting."""
    motion, trial, src = bvh_source(shared_data / "bvh/cmu/131_01.bvh")
    t = np.arange(motion.n_frames) / motion.rate_hz
    H = np.ptp(trial.positions[0, :, 2])
    own = load_character(shared_data / "bvh/cmu/131_01.bvh")
    rt = Retargeter(own, derive_mapping(own, src), src, RetargetOptions(foot_planting=True))
    res = rt.process(trial.positions, None, trial.orientations, None, t)
    L = rt.plan.legs
    assert res.contact.mean() > 0.3                                       # planting did act
    dev = np.linalg.norm(res.joint_positions - trial.positions, axis=-1)  # [F, J] m
    lines = [f"onto itself: largest joint deviation {1e3 * dev.max():.3f} mm ({100 * dev.max() / H:.4f} % of the "
             f"height), frames with a leg joint over 1 % of the height off: {(dev.max(1) > 0.01 * H).sum()}"]
    for i in range(2):
        leg = [L["hip"][i], L["knee"][i], L["ankle"][i], L["toe"][i]]
        a = trial.positions[:, L["ankle"][i]]
        slow = np.r_[False, np.linalg.norm(np.diff(a, axis=0), axis=1) < 2e-3]
        assert slow.sum() > 300
        assert dev[slow][:, leg].max() < 0.01
    ratio = _largest_steps(res.joint_positions) / np.maximum(_largest_steps(trial.positions), 1e-9)
    assert ratio.max() <= 1.2
    lines.append(f"  joint step / source's largest step: max {ratio.max():.3f}")
    mix = load_character("mixamo")
    m = derive_mapping(mix, src)
    out = {p: Retargeter(mix, m, src, RetargetOptions(foot_planting=p)) for p in (False, True)}
    got = {p: r.process(trial.positions, None, trial.orientations, None, t) for p, r in out.items()}
    L = out[True].plan.legs
    legs = np.r_[L["hip"], L["knee"], L["ankle"], L["toe"]]
    change = np.linalg.norm(got[True].joint_positions - got[False].joint_positions, axis=-1)
    c = got[True].contact
    held = c[1:] & c[:-1]
    sa = out[True].plan.ratio * trial.positions[:, L["src_ankle"], :2]
    skate = {p: np.linalg.norm(np.diff(g.joint_positions[:, L["ankle"], :2] - sa, axis=0), axis=-1)[held]
             for p, g in got.items()}
    steps = _largest_steps(got[True].joint_positions) / np.maximum(_largest_steps(got[False].joint_positions), 1e-9)
    lines.append(f"onto Mixamo: planting moves a leg joint by at most {1e3 * change[:, legs].max():.1f} mm "
                 f"(mean {1e3 * change[:, legs].mean():.2f} mm) and removes skating: mean "
                 f"{1e3 * skate[False].mean():.2f} -> {1e3 * skate[True].mean():.2f}, max {1e3 * skate[False].max():.2f} -> "
                 f"{1e3 * skate[True].max():.2f} mm/frame; step / unplanted largest: max {steps.max():.3f}")
    print("\nCMU 131_01 with foot planting:\n" + "\n".join(lines))
    assert skate[True].mean() < 0.25 * skate[False].mean()
    assert steps.max() <= 1.2
