"""Synthetic actor: exact ground truth, gym coverage, smoothness, determinism, imperfections."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.kinematics.layout import LayoutError
from mocapgraph.kinematics.skeleton import SkeletonDefinition
from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor, synthesize

LAYOUTS = ["kiip_full_body", "plug_in_gait", "qualisys", "opensim_gait2392", "lower_body", "one_arm"]
IMPERFECT = CaptureOptions(noise_mm=1.5, wobble_mm=3.0, dropout_rate_hz=0.3, shadow_rate_hz=0.5,
                           swap_rate_hz=0.2)


@pytest.fixture(scope="module")
def kiip():
    return SyntheticActor("kiip_full_body", rate=60.0, seed=3).capture()


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R [T,3,3] minimising |R (a - mean a) - (b - mean b)| for a [K,3], b [T,K,3]."""
    a0 = a - a.mean(axis=0)
    b0 = b - b.mean(axis=1, keepdims=True)
    u, _, vt = np.linalg.svd(np.einsum("tki,kj->tij", b0, a0))
    d = np.sign(np.linalg.det(u @ vt))
    u[:, :, 2] *= d[:, None]
    return u @ vt


@pytest.mark.parametrize("layout", LAYOUTS)
def test_ground_truth_is_exact(layout):
    cap = SyntheticActor(layout, rate=30.0, seed=1).capture()
    sk = cap.skeleton
    assert cap.limb_exact.all()
    assert cap.valid.all() and np.isfinite(cap.markers).all()
    R = Rotation.from_quat(cap.limb_quat.reshape(-1, 4), scalar_first=True).as_matrix().reshape(cap.n_frames, -1, 3, 3)
    lmi = sk.limb_marker_index()
    for l in range(sk.n_limbs):
        idx = lmi[l][lmi[l] >= 0]
        np.testing.assert_allclose(cap.markers[:, idx].mean(axis=1), cap.limb_centroids[:, l], atol=1e-12)
        if len(idx) < 3:
            continue   # 2 markers + a joint point (Plug-in Gait thigh): orientation not from markers alone
        # limb orientation: an independent SVD fit of the markers agrees with the truth
        Rf = _kabsch(cap.base_markers[idx], cap.markers[:, idx])
        assert np.abs(Rf - R[:, l]).max() < 1e-9, sk.limb_names[l]
    for j in range(sk.n_joints):
        for k in range(2):
            l = sk.joint_limbs[j, k]
            idx = lmi[l][lmi[l] >= 0]
            pred = cap.markers[:, idx].mean(axis=1) + np.einsum("tab,b->ta", R[:, l], cap.joint_offsets[j, k])
            assert np.abs(pred - cap.joint_centres[:, j]).max() < 1e-9, (sk.joint_names[j], k)
    # base pose: the hold reproduces the base markers and identity orientations
    base = cap.phase_slice("base")
    np.testing.assert_allclose(cap.markers[base], np.broadcast_to(cap.base_markers, cap.markers[base].shape), atol=1e-12)
    np.testing.assert_allclose(np.abs(cap.limb_quat[base][..., 0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(cap.joint_centres[0], cap.base_joint_centres, atol=1e-12)


def test_rigid_geometry_and_marker_placement(kiip):
    sk = kiip.skeleton
    lmi = sk.limb_marker_index()
    for l in range(sk.n_limbs):
        idx = lmi[l][lmi[l] >= 0]
        P = kiip.markers[:, idx]
        d = np.linalg.norm(P[:, :, None] - P[:, None], axis=-1)
        assert np.abs(d - d[:1]).max() < 1e-9
        sv = np.linalg.svd(kiip.base_markers[idx] - kiip.base_markers[idx].mean(0), compute_uv=False)
        assert sv[1] > 0.02, f"{sk.limb_names[l]} markers nearly collinear"
    # bone lengths: joints at both ends of a limb keep their distance
    for j in range(sk.n_joints):
        p = sk.joint_parent[j]
        if p >= 0:
            L = np.linalg.norm(kiip.joint_centres[:, j] - kiip.joint_centres[:, p], axis=1)
            assert np.ptp(L) < 1e-9 and L[0] > 0.02
    # markers sit 3-13 cm from their limb's bone line (proximal joint -> distal joint or tip)
    geo = SyntheticActor("kiip_full_body", seed=3).geometry
    act = SyntheticActor("kiip_full_body", seed=3)
    for m in range(sk.n_markers):
        s = act.limb_segment[sk.marker_limb[m]]
        a, b = geo.proximal[s], geo.distal[s]
        u = (b - a) / np.linalg.norm(b - a)
        v = kiip.base_markers[m] - a
        dist = np.linalg.norm(v - (v @ u) * u)
        assert 0.03 <= dist <= 0.13, sk.marker_labels[m]


def test_hinges_turn_only_about_their_axis():
    cap = SyntheticActor("plug_in_gait", rate=30.0, seed=2).capture()
    sk = cap.skeleton
    assert sk.joint_hinge.sum() == 8   # elbows, wrists, knees, ankles
    rv = Rotation.from_quat(cap.joint_quat.reshape(-1, 4), scalar_first=True).as_rotvec().reshape(cap.n_frames, -1, 3)
    for j in np.flatnonzero(sk.joint_hinge):
        ax = cap.joint_dof_axes[j, 0]
        off_axis = np.linalg.norm(np.cross(rv[:, j], ax), axis=1)
        assert off_axis.max() < 1e-9, sk.joint_names[j]
        assert np.ptp(rv[:, j] @ ax) > np.radians(45)


def test_gym_turns_every_major_joint_dof_45_degrees(kiip):
    sk = kiip.skeleton
    q = kiip.joint_quat[kiip.phase_slice("gym")]
    assert kiip.joint_major.sum() >= 14
    for j in np.flatnonzero(kiip.joint_major):
        for d in range(kiip.joint_dof_count[j]):
            ax = kiip.joint_dof_axes[j, d]
            twist = 2.0 * np.arctan2(q[:, j, 1:] @ ax, q[:, j, 0])
            assert np.degrees(np.ptp(twist)) >= 45.0, (sk.joint_names[j], kiip.joint_dof_names[j][d])


def test_phases_cover_the_session_in_order(kiip):
    ph = kiip.phases
    order = ["base", "gym_dof0", "gym_dof1", "gym_dof2", "gym_circle", "walk", "reach", "turn",
             "walk_back", "kick", "turn_back"]
    assert ph[order[0]][0] == 0 and ph[order[-1]][1] == kiip.n_frames
    for a, b in zip(order, order[1:]):
        assert ph[a][1] == ph[b][0] and ph[a][0] < ph[a][1]
    assert ph["base"][1] == round(1.0 * kiip.rate)
    assert ph["gym"] == (ph["gym_dof0"][0], ph["gym_circle"][1])
    # walking moves the actor forward along +X, the loop returns it home facing the same way
    root = kiip.joint_centres[:, kiip.skeleton.joint_index("waist")]
    w = kiip.phase_slice("walk")
    assert root[w.stop - 1, 0] - root[w.start, 0] > 3.0
    np.testing.assert_allclose(root[-1], root[0], atol=0.01)
    # the turn faces the actor backwards: the pelvis X axis points to -X
    R = Rotation.from_quat(kiip.limb_quat[kiip.phase_slice("turn").stop, 0], scalar_first=True).as_matrix()
    assert R[0, 0] < -0.95


def test_motion_is_smooth():
    # A C1 trajectory has bounded acceleration: doubling the rate must not grow the peak
    # second difference / dt^2 (a velocity jump would double it).
    peaks = []
    for rate in (120.0, 240.0):
        cap = SyntheticActor("kiip_full_body", rate=rate, seed=0).capture()
        acc = np.diff(cap.markers, n=2, axis=0) * rate ** 2
        peaks.append(np.abs(acc).max())
    assert peaks[0] < 400.0
    assert peaks[1] < 1.15 * peaks[0]


def test_longer_sessions_repeat_the_performance_and_chunks_match_whole():
    act = SyntheticActor("lower_body", rate=50.0, duration_s=70.0, seed=5, options=IMPERFECT)
    assert act.n_frames == 3500 and "walk#2" in act.phases and "kick#2" in act.phases
    whole = act.capture()
    parts = list(act.chunks(777))
    for field in ("markers", "valid", "joint_centres", "limb_quat", "times"):
        joined = np.concatenate([getattr(p, field) for p in parts])
        np.testing.assert_array_equal(joined, getattr(whole, field), err_msg=field)
    assert sum(len(p.swaps) for p in parts) >= len(whole.swaps)
    mid = act.capture(1000, 1200)
    np.testing.assert_array_equal(mid.markers, whole.markers[1000:1200])
    assert mid.phase_slice("base") == slice(0, 0)
    empty = act.capture(20, 20)
    assert empty.markers.shape == (0, act.skeleton.n_markers, 3) and empty.limb_quat.shape[0] == 0
    with pytest.raises(ValueError):
        act.capture(10, 5000)


def test_determinism_with_seed():
    a = synthesize("one_arm", rate=40.0, seed=11, options=IMPERFECT)
    b = synthesize("one_arm", rate=40.0, seed=11, options=IMPERFECT)
    c = synthesize("one_arm", rate=40.0, seed=12, options=IMPERFECT)
    np.testing.assert_array_equal(a.markers, b.markers)
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_array_equal(a.swaps, b.swaps)
    assert not np.array_equal(a.base_markers, c.base_markers)


def test_noise_std_matches_option_and_truth_is_untouched():
    clean = SyntheticActor("kiip_full_body", rate=60.0, seed=4).capture()
    noisy = SyntheticActor("kiip_full_body", rate=60.0, seed=4, options=CaptureOptions(noise_mm=2.0)).capture()
    err = (noisy.markers - clean.markers) * 1e3
    assert abs(err.std() - 2.0) < 0.05
    assert abs(err.mean()) < 0.02
    for f in ("joint_centres", "limb_quat", "joint_quat", "limb_centroids", "base_markers", "joint_offsets"):
        np.testing.assert_array_equal(getattr(noisy, f), getattr(clean, f), err_msg=f)


def band_leak(x: np.ndarray, rate: float, band: tuple[float, float]) -> float:
    """Fraction of the energy of ``x`` (time on axis 0) outside the frequency ``band``, Hz."""
    power = np.abs(np.fft.rfft(x - x.mean(axis=0), axis=0)) ** 2
    f = np.fft.rfftfreq(x.shape[0], 1.0 / rate)
    inside = (f >= band[0]) & (f <= band[1])
    return float(power[~inside].sum() / power.sum())


def test_soft_tissue_wobble_is_smooth_and_limb_relative():
    # Expectations from the documented options (4 mm RMS per axis in the limb frame, 0.2-2 Hz) and
    # the ground-truth limb orientations, never from the actor's own draws.
    clean = SyntheticActor("lower_body", rate=100.0, seed=6).capture()
    wob = SyntheticActor("lower_body", rate=100.0, seed=6, options=CaptureOptions(wobble_mm=4.0)).capture()
    d = (wob.markers - clean.markers) * 1e3
    # correlated in time: white noise of this RMS would step ~1.4 x RMS per frame
    assert np.sqrt((np.diff(d, axis=0) ** 2).mean()) < 0.1 * 4.0
    np.testing.assert_array_equal(wob.joint_centres, clean.joint_centres)
    sk = wob.skeleton
    R = Rotation.from_quat(wob.limb_quat.reshape(-1, 4), scalar_first=True).as_matrix().reshape(wob.n_frames, -1, 3, 3)
    local = np.einsum("tmba,tmb->tma", R[:, sk.marker_limb], d)  # in the owning limb's frame
    per_axis = np.sqrt((local ** 2).mean(axis=(0, 1)))
    assert np.allclose(per_axis, 4.0, atol=0.2), per_axis  # measured 3.96-4.02 mm
    # Limb-relative: in the limb's frame it stays in its band (measured 0.3 % of the energy outside
    # 0.15-2.2 Hz), while in the world frame the limb's turning spreads it (2.4 %). A wobble added
    # in the world frame shows the opposite.
    leak_local = band_leak(local, 100.0, (0.15, 2.2))
    leak_world = band_leak(d, 100.0, (0.15, 2.2))
    assert leak_local < 0.01 and leak_local < leak_world / 3, (leak_local, leak_world)


def test_occlusions_and_swaps():
    clean = SyntheticActor("kiip_full_body", rate=60.0, seed=8).capture()
    opts = CaptureOptions(dropout_rate_hz=0.2, shadow_rate_hz=0.4, swap_rate_hz=0.3)
    cap = SyntheticActor("kiip_full_body", rate=60.0, seed=8, options=opts).capture()
    sk = cap.skeleton
    assert np.array_equal(np.isnan(cap.markers).any(-1), ~cap.valid)
    assert np.isnan(cap.markers[~cap.valid]).all()
    assert 0.005 < 1.0 - cap.valid.mean() < 0.2
    assert cap.valid[cap.phase_slice("base")].all(), "base hold stays clean"
    # some frames lose every marker of one limb (limb shadowing)
    whole_limb_hidden = False
    for l in range(sk.n_limbs):
        own = np.flatnonzero(sk.marker_limb == l)
        whole_limb_hidden |= bool((~cap.valid[:, own]).all(axis=1).any())
    assert whole_limb_hidden
    # swaps: inside each window two labels exchange positions (where visible), outside they agree
    assert len(cap.swaps) >= 3
    swapped = np.zeros(cap.valid.shape, bool)
    for a, b, m1, m2 in cap.swaps:
        assert sk.marker_limb[m1] == sk.marker_limb[m2] or \
            {int(sk.marker_limb[m1]), int(sk.marker_limb[m2])} in [set(map(int, p)) for p in sk.joint_limbs]
        swapped[a:b, [m1, m2]] = True
    simple = [(a, b, m1, m2) for a, b, m1, m2 in cap.swaps
              if not any((o[0] < b and o[1] > a and {o[2], o[3]} & {m1, m2}) for o in cap.swaps if tuple(o) != (a, b, m1, m2))]
    assert simple
    for a, b, m1, m2 in simple:
        v = cap.valid[a:b, m1]
        np.testing.assert_array_equal(cap.markers[a:b, m1][v], clean.markers[a:b, m2][v])
    ok = cap.valid & ~swapped
    np.testing.assert_array_equal(cap.markers[ok], clean.markers[ok])
    np.testing.assert_array_equal(cap.joint_centres, clean.joint_centres)


def test_body_parameters_scale_the_skeleton():
    from mocapgraph.kinematics.synthetic.body import BodyParams
    short = SyntheticActor("lower_body", rate=10.0, body=BodyParams(height=1.5)).capture()
    tall = SyntheticActor("lower_body", rate=10.0, body=BodyParams(height=2.0)).capture()
    sk = short.skeleton
    hip, knee = sk.joint_index("hip_l"), sk.joint_index("knee_l")
    thigh = lambda c: np.linalg.norm(c.base_joint_centres[hip] - c.base_joint_centres[knee])
    assert thigh(short) == pytest.approx(0.245 * 1.5) and thigh(tall) == pytest.approx(0.245 * 2.0)
    jit = SyntheticActor("lower_body", rate=10.0, proportion_jitter=0.05, seed=1)
    assert thigh(jit.capture(0, 1)) != pytest.approx(thigh(short) / 1.5 * 1.75)


def test_unknown_limb_names_are_a_layout_error():
    sk = SkeletonDefinition.from_layout_dict({"name": "odd", "limbs": [
        {"name": "pelvis", "markers": ["A", "B", "C"]},
        {"name": "tail", "parent": "pelvis", "joint": {"name": "j", "type": "ball"}, "markers": ["D", "E", "F"]}]},
        source="odd.yaml")
    with pytest.raises(LayoutError, match=r"odd\.yaml: limb `tail`"):
        SyntheticActor(sk)


def test_ball_shared_marker_flags_the_borrowing_limb():
    sk = SkeletonDefinition.from_layout_dict({"name": "s", "limbs": [
        {"name": "pelvis", "markers": ["A", "B", "C"]},
        {"name": "thigh_l", "parent": "pelvis", "joint": {"name": "hip_l", "type": "ball"},
         "markers": ["D", "E"], "shared": ["A"]}]})
    cap = SyntheticActor(sk, rate=20.0).capture()
    assert list(cap.limb_exact) == [True, False]
