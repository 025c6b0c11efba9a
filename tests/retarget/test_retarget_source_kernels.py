"""The compiled one-frame rotations_from_points (source_kernels) against the numpy reference and ground truth."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.formats.kinect_csv import KINECT_V1_JOINTS, KINECT_V1_PARENTS, read_kinect_csv
from mocapgraph.kinematics.quaternion import quat_rotate
from mocapgraph.retarget.source import (kinect_source, plan_point_rotations, rotations_from_points,
                                                   rotations_from_points_frame, skeleton_source)

RECORDINGS = ["Ges01_wavehand", "Ges02_balancinghands", "Ges03_drawlines", "Ges04_comehere", "Ges05_demopoint"]
V1_ALIAS = {"HipCenter": "SpineBase", "Spine": "SpineMid", "ShoulderCenter": "SpineShoulder"}


def _kernel_minus_numpy(plan, pts: np.ndarray) -> tuple[float, np.ndarray]:
    """Largest |kernel - numpy| over frames [F, P, 3] run one at a time through the kernel, and the
    kernel's rotations [F, P, 4]; the NaN rows must be the same (whole quaternions)."""
    with np.errstate(invalid="ignore", divide="ignore"):     # a zero-length bone: NaN, as meant
        ref = rotations_from_points(plan, pts)
    got = np.stack([rotations_from_points_frame(plan, p) for p in pts])
    nan = np.isnan(got)
    assert (nan == np.isnan(ref)).all()
    assert (nan.any(-1) == nan.all(-1)).all()
    fin = ~nan
    return (float(np.abs(got[fin] - ref[fin]).max()) if fin.any() else 0.0), got


def _v2(shared_data, name):
    t = read_kinect_csv(shared_data / "kinect2" / f"{name}.csv", ground="feet")
    return t, kinect_source(t.names, t.parents)


def _missing(t, seed: int) -> np.ndarray:
    """The recording's points, NaN where not Tracked (as the live path gets them) and at 5 % more."""
    drop = (t.tracking_state != 2) | (np.random.default_rng(seed).random(t.tracking_state.shape) < 0.05)
    return np.where(drop[..., None], np.nan, t.positions)


@pytest.mark.parametrize("best_fit", [True, False], ids=["best_fit", "triad"])
def test_kernel_matches_numpy_on_every_kinect_v2_recording(shared_data, best_fit):
    """Every frame of every recording, as recorded, with joints missing, and mirrored (y -> -y, a
    mirror-mode sensor: the girdles' best fit then has a reflection to refuse): the kernel equals
    rotations_from_points to 1e-12, NaN exactly where it is NaN."""
    lines = []
    for i, name in enumerate(RECORDINGS):
        t, src = _v2(shared_data, name)
        plan = plan_point_rotations(src, best_fit=best_fit)
        assert (plan.kind == 3).sum() == (2 if best_fit else 0)
        full, got = _kernel_minus_numpy(plan, t.positions)
        assert np.isfinite(got).all()
        holes, got = _kernel_minus_numpy(plan, _missing(t, i))
        n_nan = int(np.isnan(got[..., 0]).sum())
        assert n_nan > 0
        mirrored, _ = _kernel_minus_numpy(plan, t.positions * (1.0, -1.0, 1.0))
        lines.append(f"  {name:<22} {len(t.positions):4d} frames: {full:.1e} as recorded, {holes:.1e} with missing "
                     f"points ({n_nan} NaN rotations), {mirrored:.1e} mirrored")
        assert max(full, holes, mirrored) < 1e-12, name
    print(f"\nkernel vs numpy rotations_from_points ({'best fit' if best_fit else 'TRIAD'} girdles), max |dq|:\n"
          + "\n".join(lines))


def test_kernel_matches_numpy_on_the_v1_relabelling(shared_data):
    """The recordings relabelled as Kinect v1's 20 joints (no Neck: ShoulderCenter fits Head and
    shoulders directly), with missing points: kernel == numpy to 1e-12."""
    worst = 0.0
    for i, name in enumerate(RECORDINGS):
        t, _ = _v2(shared_data, name)
        cols = [t.names.index(V1_ALIAS.get(n, n)) for n in KINECT_V1_JOINTS]
        src = kinect_source(KINECT_V1_JOINTS, KINECT_V1_PARENTS)
        plan = plan_point_rotations(src)
        assert (plan.kind == 3).sum() == 2
        pts = _missing(t, 10 + i)[:, cols]
        err, got = _kernel_minus_numpy(plan, pts)
        assert np.isnan(got).any() and np.isfinite(got).any()
        worst = max(worst, err, _kernel_minus_numpy(plan, t.positions[:, cols])[0])
    print(f"\nKinect v1 relabelling: kernel vs numpy max |dq| {worst:.1e}")
    assert worst < 1e-12


def test_girdles_of_a_mirrored_frame_are_scipys_best_proper_rotation(shared_data):
    """On mirrored frames (a reflection of the body, so the raw Kabsch solution is improper) the
    kernel's SpineBase and SpineShoulder rotations are scipy's align_vectors of their child bones
    onto their rest directions (equal weights, proper rotation)."""
    t, src = _v2(shared_data, "Ges04_comehere")
    plan = plan_point_rotations(src)
    pts = t.positions[::7] * (1.0, -1.0, 1.0)
    worst = 0.0
    for p in pts:
        q = rotations_from_points_frame(plan, p)
        for g, j in enumerate(plan.fit_joints):
            kids = plan.fit_kids[g][plan.fit_kids[g] >= 0]
            cur = p[kids] - p[j]
            cur /= np.linalg.norm(cur, axis=1, keepdims=True)
            assert np.linalg.det(cur.T @ plan.fit_rest[g, :len(kids)]) < 0     # a reflection indeed
            ref, _ = Rotation.align_vectors(cur, plan.fit_rest[g, :len(kids)])
            worst = max(worst, (ref.inv() * Rotation.from_quat(q[j], scalar_first=True)).magnitude())
    print(f"\nmirrored girdles vs scipy align_vectors: max {np.degrees(worst):.1e} deg over {len(pts)} frames")
    assert worst < 1e-9


def test_a_rigidly_moved_rest_pose_gives_that_rotation_everywhere():
    """Ground truth: the Kinect v2 T-pose turned by a known rotation and moved gives every joint
    exactly that world rotation (the rest pose is identity by construction)."""
    from mocapgraph.formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
    src = kinect_source(KINECT_V2_JOINTS, KINECT_V2_PARENTS)
    plan = plan_point_rotations(src)
    worst = 0.0
    for r in Rotation.random(20, random_state=7):
        p = r.apply(src.rest_points) + (0.3, -1.2, 0.9)
        q = rotations_from_points_frame(plan, p)
        worst = max(worst, float((r.inv() * Rotation.from_quat(q, scalar_first=True)).magnitude().max()))
    assert worst < 1e-9
    assert np.allclose(rotations_from_points_frame(plan, src.rest_points), [1.0, 0, 0, 0], atol=1e-12)


def test_degenerate_frames_are_nan_alike_in_kernel_and_numpy():
    """Frames where a rotation is undetermined give NaN there (and below, where it is carried) in
    both, never an arbitrary rotation: a girdle's child bones on one line, a wrist's thumb on the
    hand's line, a zero-length bone, every point missing. A forearm folded straight back (the
    shortest arc's half-turn branch) is no degeneracy: both turn the bone exactly onto it."""
    from mocapgraph.formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
    src = kinect_source(KINECT_V2_JOINTS, KINECT_V2_PARENTS)
    plan = plan_point_rotations(src)
    n = KINECT_V2_JOINTS.index
    rest = src.rest_points
    frames, nan_at = [], []

    def case(edit, expect_nan):
        p = rest.copy()
        edit(p)
        frames.append(p)
        nan_at.append(expect_nan)

    def collinear_pelvis(p):
        up = p[n("SpineMid")] - p[n("SpineBase")]
        p[n("HipLeft")] = p[n("SpineBase")] - 0.5 * up
        p[n("HipRight")] = p[n("SpineBase")] - 0.25 * up

    def thumb_on_hand_line(p):
        p[n("ThumbLeft")] = p[n("WristLeft")] + 0.5 * (p[n("HandLeft")] - p[n("WristLeft")])

    def zero_thigh(p):
        p[n("KneeLeft")] = p[n("HipLeft")]

    def fold_forearm(p):
        p[n("WristLeft")] = 2.0 * p[n("ElbowLeft")] - p[n("WristLeft")]

    case(collinear_pelvis, [n(x) for x in ("SpineBase", "SpineMid", "HipLeft", "KneeLeft", "AnkleLeft", "FootLeft",
                                           "HipRight", "KneeRight", "AnkleRight", "FootRight")])
    case(thumb_on_hand_line, [n("WristLeft"), n("HandLeft"), n("HandTipLeft"), n("ThumbLeft")])
    case(zero_thigh, [n("HipLeft")] + [n(x) for x in ("KneeLeft", "AnkleLeft", "FootLeft")])
    case(fold_forearm, [])
    case(lambda p: p.fill(np.nan), list(range(len(rest))))
    err, got = _kernel_minus_numpy(plan, np.stack(frames))
    assert err < 1e-12
    for f, e in enumerate(nan_at):
        assert set(np.flatnonzero(np.isnan(got[f, :, 0]))) == set(e), f
    folded = quat_rotate(got[3, n("ElbowLeft")], plan.rest_primary[n("ElbowLeft")])
    assert np.allclose(folded, -plan.rest_primary[n("ElbowLeft")], atol=1e-12)


def test_a_symmetric_mirror_image_has_no_best_rotation():
    """A girdle of three orthogonal unit bones, mirrored: the half-turns about every axis in the
    mirror plane fit it equally well, so there is no best rotation and both give NaN (FIT_MIN_GAP);
    the same girdle at rest, or turned, gives its rotation exactly."""
    offs = np.array([[0.0, 0, 1], [1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.5, 0, 0], [0, 0.5, 0], [0, 0, 0.5]])
    src = skeleton_source(list("rabcdef"), [-1, 0, 0, 0, 1, 2, 3], offs, has_orientations=False)
    plan = plan_point_rotations(src)
    assert plan.kind[0] == 3
    r = Rotation.from_rotvec([0.3, -0.2, 0.5])
    pts = np.stack([src.rest_points, r.apply(src.rest_points), src.rest_points * (1.0, -1.0, 1.0)])
    err, got = _kernel_minus_numpy(plan, pts)
    assert err < 1e-12
    assert np.allclose(got[0], [1.0, 0, 0, 0], atol=1e-12)
    assert (r.inv() * Rotation.from_quat(got[1], scalar_first=True)).magnitude().max() < 1e-9
    assert np.isnan(got[2]).all()


def test_warm_compiles_what_the_live_path_calls():
    """warm_source_kernels() covers the signatures a live frame uses (points writable, or read-only when decoded
    from a message buffer), so a node never compiles on its first frame."""
    from mocapgraph.formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
    from mocapgraph.retarget.source_kernels import point_rotations
    from mocapgraph.retarget.warmup import warm_source_kernels
    warm_source_kernels()
    seen = set(point_rotations.signatures)
    plan = plan_point_rotations(kinect_source(KINECT_V2_JOINTS, KINECT_V2_PARENTS))
    frozen = np.frombuffer(np.random.default_rng(0).normal(size=75).tobytes()).reshape(25, 3)
    assert not frozen.flags.writeable
    rotations_from_points_frame(plan, frozen)
    rotations_from_points_frame(plan, frozen.copy())
    rotations_from_points_frame(plan, frozen.tolist())
    assert set(point_rotations.signatures) == seen


def test_a_degenerate_girdle_in_a_live_stream_is_held_and_flagged(shared_data):
    """A live Kinect stream with one frame whose hips lie on the spine line (no pelvis rotation
    exists): the retargeter holds the pelvis there and flags it estimated, never good, outputs stay
    finite, the next frame is good again, and the one-frame path equals the batched one."""
    from mocapgraph.formats.mapping_file import load_mapping
    from mocapgraph.retarget.character import standard_20
    from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
    from retarget_support import live_minus_batch
    t, src = _v2(shared_data, "Ges01_wavehand")
    n = t.names.index
    pts, ok = t.positions[:40].copy(), t.tracking_state[:40] == 2
    f = 20
    assert ok[f - 1:f + 2].all()
    up = pts[f, n("SpineMid")] - pts[f, n("SpineBase")]
    pts[f, n("HipLeft")] = pts[f, n("SpineBase")] - 0.5 * up
    pts[f, n("HipRight")] = pts[f, n("SpineBase")] - 0.3 * up
    ch, mapping = standard_20(1.75), load_mapping("kinect_v2_standard_20")
    rt = Retargeter(ch, mapping, src, RetargetOptions())
    res = [rt.process(pts[i:i + 1], ok[i:i + 1]) for i in range(len(pts))]
    hip = ch.index("HipCenter")
    assert [int(r.joint_quality[0, hip]) for r in res[f - 1:f + 2]] == [2, 1, 2]
    assert np.allclose(res[f].local_rotations[0, hip], res[f - 1].local_rotations[0, hip], atol=1e-12)   # held
    assert all(np.isfinite(r.local_rotations).all() and np.isfinite(r.joint_positions).all() for r in res)
    assert live_minus_batch(ch, mapping, src, RetargetOptions(), pts, ok, None, n=len(pts)) < 1e-9


@pytest.mark.parametrize("spread", [1e-2, 1e-3, 1e-4])
def test_a_nearly_collinear_pelvis_is_still_determined_and_alike(spread):
    """Hips just off the spine line (spread x the spine length sideways): a rotation exists, both
    give it, equal to 1e-12 (only far closer, at FIT_MIN_GAP, does it become NaN)."""
    from mocapgraph.formats.kinect_csv import KINECT_V2_JOINTS, KINECT_V2_PARENTS
    src = kinect_source(KINECT_V2_JOINTS, KINECT_V2_PARENTS)
    plan = plan_point_rotations(src)
    n = KINECT_V2_JOINTS.index
    p = src.rest_points.copy()
    up = p[n("SpineMid")] - p[n("SpineBase")]
    side = np.array([0.0, 1.0, 0.0]) * np.linalg.norm(up)
    p[n("HipLeft")] = p[n("SpineBase")] - 0.5 * up + spread * side
    p[n("HipRight")] = p[n("SpineBase")] - 0.3 * up - spread * side
    err, got = _kernel_minus_numpy(plan, p[None])
    assert np.isfinite(got).all() and err < 1e-12
