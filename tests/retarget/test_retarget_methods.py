"""Spine spread with end-point matching, roll joints by swing-twist fraction, quaternion helpers."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.retarget.character import Character
from mocapgraph.kinematics.quaternion import quat_between, quat_power, quat_rotate, swing_twist, twist_angle
from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
from mocapgraph.retarget.mapping import JointMap, Mapping, align_rest_poses, derive_mapping
from mocapgraph.retarget.source import character_from_actor, optical_points, optical_source
from mocapgraph.kinematics.synthetic.actor import SyntheticActor

from retarget_support import live_minus_batch


@pytest.fixture(scope="module")
def actor():
    cap = SyntheticActor("kiip_full_body", seed=2).capture()
    sk = cap.skeleton
    src = optical_source(sk.joint_names, sk.joint_parent, sk.joint_limbs, sk.limb_names, cap.base_joint_centres)
    perf = cap.phase_slice("performance")
    pts = optical_points(cap.joint_centres[perf], sk.joint_names)
    return cap, src, pts, cap.limb_quat[perf]


def _insert(ch: Character, after: str, before: str, names: list[str], move: tuple[str, ...] = ()) -> Character:
    """``ch`` with joints ``names`` spaced evenly on the bone after -> before (before, and the joints
    in ``move``, re-parented onto the last inserted joint)."""
    a, b = ch.index(after), ch.index(before)
    rest, _ = ch.rest_pose()
    jn = list(ch.joint_names)
    par = [ch.joint_names[p] if p >= 0 else None for p in ch.parents]
    pos = {n: rest[i] for i, n in enumerate(jn)}
    k = len(names) + 1
    for i, n in enumerate(names):
        pos[n] = rest[a] + (rest[b] - rest[a]) * (i + 1) / k
    order, parent = [], {}
    for i, n in enumerate(jn):
        order.append(n)
        parent[n] = par[i]
        if n == after:
            prev = after
            for m in names:
                order.append(m)
                parent[m] = prev
                prev = m
    parent[before] = names[-1]
    for n in move:
        parent[n] = names[-1]
    idx = {n: i for i, n in enumerate(order)}
    # parents must precede children: a stable topological order
    out, seen = [], set()
    while len(out) < len(order):
        for n in order:
            if n not in seen and (parent[n] is None or parent[n] in seen):
                out.append(n)
                seen.add(n)
    pa = np.array([-1 if parent[n] is None else out.index(parent[n]) for n in out])
    offs = np.array([pos[n] - pos[parent[n]] if parent[n] else pos[n] for n in out])
    return Character(ch.name + "+", tuple(out), pa, offs, np.tile([1.0, 0, 0, 0], (len(out), 1)))


def test_three_joint_spine_follows_a_one_segment_actor_spine(actor):
    cap, src, pts, limbs = actor
    base = character_from_actor(cap.skeleton.joint_names, cap.skeleton.joint_parent, cap.base_joint_centres)
    # the actor's spine is one segment (waist -> neck, the upper torso); this character has three
    # spine joints there: s1 at the waist, s2, s3 (the chest, carrying the upper torso)
    ch = _insert(base, "waist", "neck", ["s2", "s3"], move=("sternoclavicular_l", "sternoclavicular_r"))
    ch = Character(ch.name, tuple("s1" if n == "waist" else n for n in ch.joint_names), ch.parents, ch.rest_offsets,
                   ch.rest_rotations)
    auto = derive_mapping(base, src)
    joints = [e for e in auto.joints if e.joint != "waist"]
    joints += [JointMap("s1", "spread", None, "waist"), JointMap("s2", "spread"),
               JointMap("s3", "rotate", "upper_torso")]
    m = align_rest_poses(Mapping("optical:kiip_full_body", ch.name, tuple(joints), 1.0, auto.legs), ch, src)
    rt = Retargeter(ch, m, src, RetargetOptions(follow_bones=False))
    out = rt.process(pts, None, limbs)
    names = list(cap.skeleton.joint_names)
    neck_true = cap.joint_centres[cap.phase_slice("performance")][:, names.index("neck")]
    waist_true = cap.joint_centres[cap.phase_slice("performance")][:, names.index("waist")]
    s1 = out.joint_positions[:, ch.index("s1")]
    neck = out.joint_positions[:, ch.index("neck")]
    end_err = np.linalg.norm(neck - neck_true, axis=-1)
    # the chain bends: each spine joint takes its share of the pelvis-to-chest rotation
    local = Rotation.from_quat(out.local_rotations[:, [ch.index("s1"), ch.index("s2"), ch.index("s3")]].reshape(-1, 4),
                               scalar_first=True).magnitude().reshape(-1, 3)
    bend = Rotation.from_quat(limbs[:, 0], scalar_first=True).inv() * Rotation.from_quat(limbs[:, 1], scalar_first=True)
    print(f"\nthree-joint spine from a one-segment spine: end point (neck) mean {1000 * end_err.mean():.2f} mm, "
          f"max {1000 * end_err.max():.2f} mm; torso bend up to {np.degrees(bend.magnitude().max()):.0f} deg; "
          f"per-joint local turn mean {np.degrees(local.mean(0)).round(1)} deg")
    assert np.abs(np.linalg.norm(s1 - waist_true, axis=-1)).max() < 1e-6
    assert end_err.max() < 0.005
    assert rt.frame_path.c_correct[0]               # the end point correction, on the one-frame path too
    assert live_minus_batch(ch, m, src, RetargetOptions(follow_bones=False), pts, None, limbs) < 1e-12
    busy = bend.magnitude() > np.radians(10)
    assert busy.any() and (local[busy] > np.radians(1)).all(axis=1).mean() > 0.9   # all three share the bend


def test_roll_joints_take_exact_twist_fractions(actor):
    cap, src, pts, limbs = actor
    base = character_from_actor(cap.skeleton.joint_names, cap.skeleton.joint_parent, cap.base_joint_centres)
    ch = _insert(base, "shoulder_l", "elbow_l", ["upper_roll_l"])
    ch = _insert(ch, "elbow_l", "wrist_l", ["lower_roll_l"])
    auto = derive_mapping(base, src)
    joints = list(auto.joints) + [JointMap("upper_roll_l", roll_of="shoulder_l", roll_fraction=0.5),
                                  JointMap("lower_roll_l", roll_of="wrist_l", roll_fraction=0.3)]
    m = align_rest_poses(Mapping("optical", ch.name, tuple(joints), 1.0, {}), ch, src)
    plain = Retargeter(ch, m, src, RetargetOptions(roll=False, follow_bones=False)).process(pts, None, limbs)
    rolled = Retargeter(ch, m, src, RetargetOptions(roll=True, follow_bones=False)).process(pts, None, limbs)
    assert live_minus_batch(ch, m, src, RetargetOptions(roll=True, follow_bones=False), pts, None, limbs) < 1e-12
    # positions do not move: roll joints sit on the limb axis
    assert np.abs(rolled.joint_positions - plain.joint_positions).max() < 1e-9
    q = lambda res, n: Rotation.from_quat(res.local_rotations[:, ch.index(n)], scalar_first=True)  # noqa: E731

    def twist(rot: Rotation, axis: np.ndarray) -> np.ndarray:   # independent: scipy, projection formula
        x = rot.as_quat(scalar_first=True)
        a = axis / np.linalg.norm(axis)
        s = x[:, 1:] @ a
        return 2 * np.arctan2(s, x[:, 0])
    up_axis = ch.rest_offsets[ch.index("upper_roll_l")]
    th = twist(q(plain, "shoulder_l"), up_axis)
    th = (th + np.pi) % (2 * np.pi) - np.pi
    keep = np.abs(th) > np.radians(2)
    assert keep.sum() > 100
    roll_up = twist(q(rolled, "upper_roll_l"), up_axis)
    np.testing.assert_allclose(roll_up[keep], 0.5 * th[keep], atol=1e-9)
    # the shoulder keeps the other half, and nothing but twist moved onto the roll joint
    rest_sh = twist(q(rolled, "shoulder_l"), up_axis)
    np.testing.assert_allclose(((rest_sh + np.pi) % (2 * np.pi) - np.pi)[keep], 0.5 * th[keep], atol=1e-9)
    assert np.allclose(np.abs(q(rolled, "upper_roll_l").as_rotvec() @ (up_axis / np.linalg.norm(up_axis))),
                       q(rolled, "upper_roll_l").magnitude(), atol=1e-9)
    lo_axis = ch.rest_offsets[ch.index("wrist_l")]
    tw = twist(q(plain, "wrist_l"), lo_axis)
    tw = (tw + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(twist(q(rolled, "lower_roll_l"), lo_axis), 0.3 * tw, atol=1e-9)
    # the wrist's world orientation is unchanged
    w_plain = ch.forward_kinematics(plain.local_rotations, plain.root_positions)[1][:, ch.index("wrist_l")]
    w_roll = ch.forward_kinematics(rolled.local_rotations, rolled.root_positions)[1][:, ch.index("wrist_l")]
    assert (Rotation.from_quat(w_plain, scalar_first=True).inv() * Rotation.from_quat(w_roll, scalar_first=True)).magnitude().max() < 1e-9
    print(f"\nroll joints: upper 0.5 and lower 0.3 of the twist, exact to 1e-9 rad over {keep.sum()} twisted frames")


def test_quaternion_helpers_against_scipy():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    q = quat_between(a, b)
    np.testing.assert_allclose(np.cross(quat_rotate(q, a), b), 0, atol=1e-9)
    assert (np.sum(quat_rotate(q, a) * b, -1) > 0).all()
    # shortest arc: the angle between the vectors
    np.testing.assert_allclose(Rotation.from_quat(q, scalar_first=True).magnitude(),
                               np.arccos(np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)), atol=1e-9)
    anti = quat_between(np.array([[1.0, 0, 0]]), np.array([[-1.0, 0, 0]]))
    np.testing.assert_allclose(quat_rotate(anti, [1.0, 0, 0]), [[-1, 0, 0]], atol=1e-12)
    r = Rotation.random(100, random_state=1)
    x = r.as_quat(scalar_first=True)
    np.testing.assert_allclose(Rotation.from_quat(quat_power(x, 0.25), scalar_first=True).as_rotvec(),
                               0.25 * r.as_rotvec(), atol=1e-9)
    axis = np.array([0.0, 0.6, 0.8])
    sw, tw = swing_twist(x, axis)
    np.testing.assert_allclose((Rotation.from_quat(sw, scalar_first=True) * Rotation.from_quat(tw, scalar_first=True)).as_quat(),
                               r.as_quat(), atol=1e-9)   # q = swing * twist (sign included)
    np.testing.assert_allclose(np.cross(Rotation.from_quat(tw, scalar_first=True).as_rotvec(), axis), 0, atol=1e-9)
    # the swing does not turn about the axis: it leaves axis's own plane
    np.testing.assert_allclose(Rotation.from_quat(sw, scalar_first=True).as_rotvec() @ axis, 0, atol=1e-9)
    assert np.all(np.abs(twist_angle(tw, axis)) <= np.pi)


def test_actor_onto_mixamo_spreads_the_spine_and_lands_its_end(actor):
    """The automatic mapping onto Mixamo: Spine and Spine1 spread between the pelvis and the chest
    (Spine2, turned by the upper torso), and the neck lands on the scaled source neck."""
    from mocapgraph.formats.character_file import load_character
    cap, src, pts, limbs = actor
    mix = load_character("mixamo")
    m = derive_mapping(mix, src)
    assert m.entry("Spine").mode == "spread" and m.entry("Spine2").rotation == "upper_torso"
    rt = Retargeter(mix, m, src, RetargetOptions())
    out = rt.process(pts, None, limbs)
    assert np.isfinite(out.local_rotations).all()
    chain = rt.plan.chains[0]
    assert [mix.joint_names[j] for j in chain["joints"]] == ["Spine", "Spine1"]
    p = out.joint_positions
    want = chain["ratio"] * (pts[:, src.point("neck")] - pts[:, src.point("waist")])
    got = p[:, mix.index("Neck")] - p[:, mix.index("Spine")]
    err = np.linalg.norm(got - want, axis=-1)
    print(f"\nactor onto Mixamo: neck end point vs the scaled source spine, mean {1000 * err.mean():.2f} mm, "
          f"max {1000 * err.max():.2f} mm")
    assert err.max() < 0.005
