"""The synthetic actor (1 mm marker noise), solved, retargeted onto a character with its own skeleton
and onto that character scaled 0.8x and 1.2x, against the actor's exact ground truth."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.retarget.character import standard_20
from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
from mocapgraph.retarget.mapping import derive_mapping
from mocapgraph.retarget.source import character_from_actor, optical_points, optical_source

from retarget_support import solved_synthetic_actor


@pytest.fixture(scope="module")
def solved():
    cap, model, res = solved_synthetic_actor()
    perf = cap.phase_slice("performance")
    src = optical_source(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base)
    truth_ch = character_from_actor(cap.skeleton.joint_names, cap.skeleton.joint_parent, cap.base_joint_centres)
    return cap, model, res, src, truth_ch, perf


def _retarget(solved, ch, **opts):
    cap, model, res, src, _, perf = solved
    rt = Retargeter(ch, derive_mapping(ch, src), src, RetargetOptions(**opts))
    pts = optical_points(res.joints, model.joint_names)
    out = rt.process(pts, None, res.limb_rotation, res.limb_quality > 0, times_s=cap.times[perf])
    return rt, out


def _truth(solved, ch):
    """True joint positions and local rotations of the character with the actor's skeleton."""
    cap, model, res, src, _, perf = solved
    pts = optical_points(cap.joint_centres[perf], cap.skeleton.joint_names)
    names = list(cap.skeleton.joint_names) + ["pelvis"]
    pos = pts[:, [names.index(n) for n in ch.joint_names]]
    # each joint turns with the limb leaving it (its distal limb); the pelvis with the lower torso
    limb_of = {n: int(cap.skeleton.joint_limbs[i][1]) for i, n in enumerate(cap.skeleton.joint_names)}
    limb_of["pelvis"] = 0
    world = Rotation.from_quat(cap.limb_quat[perf][:, [limb_of[n] for n in ch.joint_names]].reshape(-1, 4),
                               scalar_first=True)
    F, J = pos.shape[:2]
    wq = world.as_quat(scalar_first=True).reshape(F, J, 4)
    par = np.maximum(ch.parents, 0)
    local = (Rotation.from_quat(wq[:, par].reshape(-1, 4), scalar_first=True).inv() * world)
    local = local.as_quat(scalar_first=True).reshape(F, J, 4)
    local[:, ch.root] = wq[:, ch.root]
    return pos, local


def test_onto_its_own_skeleton_matches_ground_truth(solved):
    ch = solved[4]
    # the character is the performer's own skeleton: root ratio 1 (the automatic leg ratio would be
    # the calibration's leg-length error, 0.2 %, i.e. 7 mm over a 3 m walk)
    rt, out = _retarget(solved, ch, scale=1.0)
    pos, local = _truth(solved, ch)
    err = np.linalg.norm(out.joint_positions - pos, axis=-1)
    ang = np.degrees((Rotation.from_quat(out.local_rotations.reshape(-1, 4), scalar_first=True).inv()
                      * Rotation.from_quat(local.reshape(-1, 4), scalar_first=True)).magnitude()).reshape(err.shape)
    print(f"\nsynthetic actor (1 mm noise) onto its own skeleton, {len(err)} frames: joints mean {1000 * err.mean():.2f} mm "
          f"(max {1000 * err.max():.1f}), local rotations mean {ang.mean():.2f} deg (95th pct {np.percentile(ang, 95):.2f})")
    assert err.mean() < 0.005
    assert ang.mean() < 2.0
    assert np.isfinite(out.local_rotations).all()


@pytest.mark.parametrize("factor", [0.8, 1.2])
def test_scaled_characters_keep_bone_lengths_stay_on_the_floor_and_do_not_skate(solved, factor):
    cap, model, res, src, truth_ch, perf = solved
    ch = truth_ch.scaled(factor, name=f"actor_x{factor}")
    ankles = [ch.index("ankle_l"), ch.index("ankle_r")]
    rest_h = ch.rest_pose()[0][ankles, 2]
    # contact frames from the ground truth (the true ankle within 1 cm of its rest height and slower
    # than 0.1 m/s, i.e. under 0.9 mm a frame), not from the retargeter's own detection
    true_a = cap.joint_centres[perf][:, [cap.skeleton.joint_names.index("ankle_l"),
                                          cap.skeleton.joint_names.index("ankle_r")]]
    true_rest = cap.base_joint_centres[[cap.skeleton.joint_names.index("ankle_l"),
                                        cap.skeleton.joint_names.index("ankle_r")], 2]
    speed = np.linalg.norm(np.diff(true_a[..., :2], axis=0), axis=-1) * cap.rate
    contact = (true_a[1:, :, 2] - true_rest < 0.01) & (speed < 0.1)
    both = contact & np.vstack([np.zeros((1, 2), bool), contact[:-1]])     # consecutive contact frames
    rows = {}
    for planting in (False, True):
        rt, out = _retarget(solved, ch, foot_planting=planting)
        p = out.joint_positions
        child = np.flatnonzero(ch.parents >= 0)
        lengths = np.linalg.norm(p[:, child] - p[:, ch.parents[child]], axis=-1)
        assert np.abs(lengths - ch.bone_lengths[child]).max() < 1e-9
        below = (rest_h - p[:, ankles, 2]).max()                        # sole below the floor, m
        a = p[:, ankles]
        step = np.diff(a[..., :2], axis=0)                              # [F-1, 2, 2]
        # skating: the ankle's step beyond the solved source ankle's own step, scaled by the root
        # ratio (planting keeps the source's own motion, its 1-2 mm solve jitter included)
        src_a = optical_points(res.joints, model.joint_names)[:, [src.point("ankle_l"), src.point("ankle_r")], :2]
        own = rt.ratio * np.diff(src_a, axis=0)
        skate = np.linalg.norm(step - own, axis=-1)[both]
        absolute = np.linalg.norm(step, axis=-1)[both]
        rows[planting] = (1000 * below, 1000 * skate.mean(), 1000 * skate.max(), rt.ratio, 1000 * absolute.mean())
    print(f"\ncharacter x{factor} (root ratio {rows[True][3]:.3f}), {both.sum()} consecutive contact frames:")
    for planting, (below, mean, mx, _, ab) in rows.items():
        print(f"  foot planting {'on ' if planting else 'off'}: deepest sole below floor {below:6.2f} mm, "
              f"skating mean {mean:.2f} max {mx:.2f} mm/frame (ankle step mean {ab:.2f} mm/frame)")
    assert both.sum() > 50
    assert rows[True][0] <= 5.0
    assert rows[True][1] <= 0.25 * rows[False][1] and rows[True][1] <= 0.1
    assert rows[True][2] <= 2.0


def test_live_frame_by_frame_equals_batch(solved):
    """One code path: a live node feeds one frame at a time, the batch command the whole trial."""
    cap, model, res, src, truth_ch, perf = solved
    ch = truth_ch.scaled(0.9)
    pts = optical_points(res.joints, model.joint_names)[:400]
    rot, rok, t = res.limb_rotation[:400], res.limb_quality[:400] > 0, cap.times[perf][:400]
    pts = pts.copy()
    pts[100:140, 3] = np.nan                       # a joint lost for a while: held, flagged
    m = derive_mapping(ch, src)
    batch = Retargeter(ch, m, src, RetargetOptions(foot_planting=True)).process(pts, None, rot, rok, t)
    live = Retargeter(ch, m, src, RetargetOptions(foot_planting=True))
    frames = [live.process(pts[f:f + 1], None, rot[f:f + 1], rok[f:f + 1], t[f:f + 1]) for f in range(400)]
    for name in ("local_rotations", "joint_positions", "root_positions", "joint_quality", "contact"):
        got = np.concatenate([getattr(x, name) for x in frames])
        np.testing.assert_allclose(got, getattr(batch, name), atol=1e-9, err_msg=name)
    assert (batch.joint_quality[100:140] == 1).any() and (batch.joint_quality[100:140] == 2).any()
    assert np.isfinite(batch.local_rotations).all()


def _leg_length(names, centres, side: str) -> float:
    i = [list(names).index(f"{j}_{side}") for j in ("hip", "knee", "ankle")]
    return float(np.linalg.norm(centres[i[1]] - centres[i[0]]) + np.linalg.norm(centres[i[2]] - centres[i[1]]))


def test_standard_20s_mid_hip_lands_on_the_actors_true_mid_hip(solved):
    """standard_20's hips stand in front of its HipCenter (Kinect's girdle) while the optical root point
    is the actor's mid-hip: the character's mid-hip (not its HipCenter) goes there. standard_20 scaled
    to the actor's true leg length (ratio 1), from the exact model and from the 1 mm noise solve,
    against the synthetic truth on every frame."""
    cap, model, res, src, _, perf = solved
    sk = cap.skeleton
    leg = np.mean([_leg_length(sk.joint_names, cap.base_joint_centres, s) for s in "lr"])
    ch0 = standard_20(1.75)
    s20_leg = sum(float(np.linalg.norm(ch0.rest_offsets[ch0.index(n)])) for n in ("KneeLeft", "AnkleLeft"))
    ch = standard_20(1.75 * leg / s20_leg)
    hips = [ch.index("HipLeft"), ch.index("HipRight")]
    true_mid = cap.joint_centres[perf][:, [sk.joint_names.index("hip_l"), sk.joint_names.index("hip_r")]].mean(1)
    # without the rule HipCenter sat on the actor's mid-hip: the character's own mid-hip this far off
    before = float(np.linalg.norm(ch.rest_pose()[0][hips].mean(0) - ch.rest_pose()[0][ch.root]))
    exact_src = optical_source(sk.joint_names, sk.joint_parent, sk.joint_limbs, sk.limb_names, cap.base_joint_centres)
    cases = {"exact model": (exact_src, optical_points(cap.joint_centres[perf], sk.joint_names), cap.limb_quat[perf], None),
             "solved, 1 mm noise": (src, optical_points(res.joints, model.joint_names), res.limb_rotation,
                                    res.limb_quality > 0)}
    errs = {}
    for what, (s, pts, rot, rok) in cases.items():
        for planting in (False, True):
            rt = Retargeter(ch, derive_mapping(ch, s), s, RetargetOptions(scale=1.0, foot_planting=planting))
            out = rt.process(pts, None, rot, rok, times_s=cap.times[perf])
            e = np.linalg.norm(out.joint_positions[:, hips].mean(1) - true_mid, axis=-1)
            errs[what, planting] = e
            print(f"\n{what}, planting {planting}: standard_20 "
                  f"mid-hip - actor's true mid-hip over {len(e)} frames: mean {1000 * e.mean():.2f} mm, "
                  f"max {1000 * e.max():.2f} mm (the source's own mid-hip: max "
                  f"{1000 * np.linalg.norm(pts[:, -1] - true_mid, axis=-1).max():.2f} mm; the rest hips' offset from "
                  f"HipCenter, where the mid-hip was before: {1000 * before:.1f} mm)")
            # ratio 1: the character's mid-hip is the source root point (pelvis, heading-aligned by the root's A)
            # up to the floor-matching constant
            want = pts[:, -1] @ rt.plan.root_A.T
            want[:, 2] = pts[:, -1, 2]
            gap = out.joint_positions[:, hips].mean(1) - want
            assert np.abs(gap - gap[0]).max() < 1e-9
    assert before > 0.04
    assert errs["exact model", False].max() < 0.001
    assert errs["exact model", True].max() < 0.001
    assert errs["solved, 1 mm noise", False].mean() < 0.005 and errs["solved, 1 mm noise", False].max() < 0.008
    assert errs["solved, 1 mm noise", True].max() < 0.008


def test_the_mid_hip_rule_is_off_where_the_root_is_the_mid_hip(solved):
    """The actor onto its own skeleton (root: pelvis, the mid-hip): nothing changes."""
    cap, model, res, src, truth_ch, perf = solved
    rt = Retargeter(truth_ch, derive_mapping(truth_ch, src), src)
    assert rt.plan.root_s is None
