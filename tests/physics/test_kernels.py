"""The compiled per-frame physics path against its numpy reference (same inputs, same state).

Controller (Eq 1 forces, Eq 2 torques, pins, targets into ``xfrc_applied``), posture database
(projection, nearest posture, P_e / Θ_e), conditioning and state read-out: each compared on the
synthetic performer's walk with hidden joints, NaN frames, a push and a reach, frame by frame
from one shared state (to ~1e-12), and a short clip tracked independently by both (qpos).
"""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mocapgraph.physics import posture_kernels as pk
from mocapgraph.physics.posture_db import PostureDB
from mocapgraph.physics.stage import load_stage
from mocapgraph.physics.synthetic_targets import synthetic_targets
from mocapgraph.physics.tracker import TargetConditioner
from mocapgraph.physics.reference import REFERENCE, ReferenceConditioner
from mocapgraph.physics.world import COMPILED, PhysicsWorld, TrackerParams

RATE = 120.0


@pytest.fixture(scope="module")
def clip():
    return synthetic_targets(17.0, 20.0, rate=RATE)


@pytest.fixture(scope="module")
def db():
    parts = [synthetic_targets(a, b, seed=1) for a, b in ((1, 17), (22, 37.5))]
    ch = parts[0].character
    return PostureDB.build(ch.joint_names, ch.parents, np.concatenate([p.positions for p in parts]),
                           np.concatenate([p.local_rotations for p in parts]), min_ssd=0.005)


def _pair(clip, stage=None):
    ws = [PhysicsWorld([clip.character], stage if stage is not None else load_stage("claro_pole"),
                       TrackerParams(), kernels=k) for k in (REFERENCE, COMPILED)]
    for w in ws:
        w.set_pose(0, clip.local_rotations[0], clip.root[0])
    return ws


def _sync(src: PhysicsWorld, dst: PhysicsWorld) -> None:
    """``dst`` put in exactly ``src``'s state (MuJoCo's integration state and the world's targets)."""
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    st = np.empty(mujoco.mj_stateSize(src.model, spec))
    mujoco.mj_getState(src.model, src.data, st, spec)
    mujoco.mj_setState(dst.model, dst.data, st, spec)
    for w in (src, dst):
        mujoco.mj_forward(w.model, w.data)
    for name in ("p_t", "v_t", "p_in", "v_in", "q_t", "w_t", "has_rot", "override", "dodge_override"):
        getattr(dst.targets, name)[...] = getattr(src.targets, name)
    dst.pins.on[...] = src.pins.on
    dst.targets.time_of_target = list(src.targets.time_of_target)


def _frame_input(clip, i, rng):
    p, q = clip.positions[i].copy(), clip.orientations[i].copy()
    if 60 <= i < 66:
        p[:] = np.nan                                  # NaN frames: no target
    hide = rng.random(len(p)) < 0.1
    p[hide] = np.nan
    q[rng.random(len(q)) < 0.1] = np.nan
    if i == 120:
        p = p + np.array([1.0, 0, 0])                  # a 1 m jump
    return p, q


def test_controller_kernels_equal_the_numpy_step_frame_by_frame(clip):
    ref, fast = _pair(clip)
    rng = np.random.default_rng(5)
    worst = dict(xfrc=0.0, force=0.0, torque=0.0, target=0.0, pins=0)
    followed = switched = 0   # frames a pin was drawn after its target / switched on or off (both exercised)
    for i in range(len(clip) - 60):
        if i == 90:
            for w in (ref, fast):
                w.push(0, "ShoulderCenter", np.array([200.0, 0, 0]), 0.1)
        if i == 150:
            for w in (ref, fast):
                w.reach(0, "HandRight", "stage/pole")
        _sync(ref, fast)
        p, q = _frame_input(clip, i, rng)
        for w in (ref, fast):
            w.set_target(0, p, q, clip.times[i])
        a, b = ref.targets, fast.targets
        assert np.array_equal(a.p_t, b.p_t, equal_nan=True) and np.array_equal(a.has_rot, b.has_rot)
        assert np.array_equal(a.p_in, b.p_in, equal_nan=True)
        worst["target"] = max(worst["target"], np.abs(a.v_t - b.v_t).max(), np.abs(a.w_t - b.w_t).max(),
                              np.abs(a.q_t - b.q_t).max(), np.abs(a.v_in - b.v_in).max())
        pins_before, on_before = ref.data.mocap_pos[ref.pins.mocap].copy(), ref.pins.on.copy()
        for w in (ref, fast):
            w.step(1.0 / RATE)
        moved = (ref.data.mocap_pos[ref.pins.mocap] != pins_before).any(1)
        followed += int((moved & on_before & ref.pins.on).sum())
        switched += int((on_before != ref.pins.on).sum())
        worst["pins"] += int((ref.pins.on != fast.pins.on).sum())
        worst["xfrc"] = max(worst["xfrc"], np.abs(ref.data.xfrc_applied - fast.data.xfrc_applied).max())
        worst["force"] = max(worst["force"], np.abs(ref.control.last_forces - fast.control.last_forces).max())
        worst["torque"] = max(worst["torque"], np.abs(ref.control.last_torques - fast.control.last_torques).max())
        assert np.abs(ref.data.mocap_pos - fast.data.mocap_pos).max() < 1e-12
    print(f"\ncompiled vs numpy controller, {len(clip) - 60} frames from one state: largest difference "
          f"xfrc_applied {worst['xfrc']:.1e} N(·m), force {worst['force']:.1e} N, torque {worst['torque']:.1e} N·m, "
          f"target velocities/orientations {worst['target']:.1e}; pins differing {worst['pins']} (pins switched "
          f"{switched} times, drawn after their targets on {followed} frames)")
    assert worst["xfrc"] < 1e-10 and worst["force"] < 1e-10 and worst["torque"] < 1e-12 and worst["target"] < 1e-12
    assert worst["pins"] == 0 and switched > 0 and followed > 0
    # both kept every force within its bound, from the values actually applied
    for w in (ref, fast):
        assert w.control.max_applied_force <= w.params.gains.max_force + 1e-9
    assert abs(ref.control.max_applied_force - fast.control.max_applied_force) < 1e-9
    assert abs(ref.control.max_applied_torque - fast.control.max_applied_torque) < 1e-12


def test_a_short_clip_tracked_by_both_paths_has_the_same_qpos(clip):
    ref, fast = _pair(clip)
    n = int(1.5 * RATE)
    for i in range(n):
        for w in (ref, fast):
            w.set_target(0, clip.positions[i], clip.orientations[i], clip.times[i])
            w.step(1.0 / RATE)
    d = np.abs(ref.data.qpos - fast.data.qpos).max()
    print(f"\n{n} frames tracked independently: largest qpos difference {d:.1e}")
    assert d < 1e-9


def test_state_readout_kernels_equal_numpy(clip):
    ref, fast = _pair(clip)
    for i in range(90):
        ref.set_target(0, clip.positions[i], clip.orientations[i], clip.times[i])
        ref.step(1.0 / RATE)
    ref.reach(0, "HandLeft", "stage/pole")
    _sync(ref, fast)
    (p0, q0, e0), (p1, q1, e1) = ref.geom_state(), fast.geom_state()
    assert np.array_equal(p0, p1)
    assert np.abs(q0 - q1).max() < 1e-12 and (q1[:, 0] >= 0).all()
    assert np.array_equal(np.isnan(e0), np.isnan(e1)) and np.nanmax(np.abs(e0 - e1)) < 1e-12
    assert np.nanmax(np.abs(ref.tracking_error() - fast.tracking_error())) < 1e-12
    leaf = clip.local_rotations[90]
    for lr in (None, leaf):
        (r0, t0), (r1, t1) = ref.local_rotations(0, lr), fast.local_rotations(0, lr)
        assert np.abs(r0 - r1).max() < 1e-12 and np.array_equal(t0, t1)


@pytest.mark.parametrize("search", ["brute", "kdtree", "split"])
def test_conditioning_and_database_kernels_equal_numpy(clip, db, search):
    """Every compiled route: one kernel call (brute force), the k-d tree between two kernels, and
    the split calls a profiled conditioner makes."""
    ch = clip.character
    db.search_compiled = "brute" if search == "split" else search
    conds = [ReferenceConditioner(ch, db), TargetConditioner(ch, db)]
    if search == "split":
        conds[1].profile = {}
    rng = np.random.default_rng(3)
    worst = 0.0
    for i in range(len(clip)):
        p, r, root = clip.positions[i].copy(), clip.local_rotations[i].copy(), clip.root[i].copy()
        p[rng.random(ch.n_joints) < 0.15] = np.nan
        r[rng.random(ch.n_joints) < 0.1] = np.nan
        r[rng.random(ch.n_joints) < 0.05] *= 1.01                     # not unit: missing
        if i % 50 == 0:
            p[:] = np.nan                                              # nothing usable: hold
        if i % 37 == 0:
            root[:] = np.nan
        if i % 41 == 0:
            p[ch.root] = np.nan
            root[:] = np.nan                                           # no root at all
        if i % 29 == 0:
            p[ch.index("HipLeft"), 2] = np.nan                         # a partly missing row
        q = (rng.random(ch.n_joints) > 0.1).astype(np.int8) * 2 if i % 3 == 0 else None
        a, b = (c.condition(p, r, root, q) for c in conds)
        assert a.held == b.held and a.match == b.match and np.array_equal(a.filled, b.filled), i
        for x, y in ((a.positions, b.positions), (a.orientations, b.orientations)):
            assert np.array_equal(np.isnan(x), np.isnan(y)), i
            worst = max(worst, np.nanmax(np.abs(x - y), initial=0.0))
    assert conds[0].filled_frames == conds[1].filled_frames > 100
    assert conds[0].held_frames == conds[1].held_frames > 0
    print(f"\ncompiled ({search}) vs numpy conditioning over {len(clip)} frames with holes: largest difference "
          f"{worst:.1e}")
    assert worst < 1e-12
    if search == "split":
        assert conds[1].profile["database"] > 0


@pytest.mark.parametrize("size", [300, 10000])
def test_brute_force_kernel_finds_the_numpy_nearest(size):
    rng = np.random.default_rng(size)
    red = rng.normal(0, 0.3, (size, 7))
    sq = (red * red).sum(1)
    qs = red[rng.integers(0, size, 200)] + rng.normal(0, 0.02, (200, 7))
    dist = np.empty(size)
    red_t = np.ascontiguousarray(red.T)
    for q in qs:
        i = pk.nearest(q, red_t, sq, dist)
        d = ((red - q) ** 2).sum(1)
        assert d[i] <= d.min() + 1e-12


def test_apply_wrenches_kernel_moves_the_model_as_mj_applyFT(clip):
    """The kernel's xfrc_applied rows ([f, (p - xipos) x f] summed per body) equal mj_applyFT of each
    force at its joint point, judged by MuJoCo's own accelerations."""
    from mocapgraph.physics import controller_kernels as ck
    w = PhysicsWorld([clip.character])
    w.set_pose(0, clip.local_rotations[200], clip.root[200])
    rng = np.random.default_rng(4)
    w.data.qvel[:] = rng.normal(0, 0.5, w.model.nv)
    mujoco.mj_forward(w.model, w.data)
    p = w.readout.point_positions()
    f = rng.normal(0, 50, p.shape)
    ck.apply_wrenches(w.control.sim, w.control.points, f, w.index.b_body, np.zeros((len(w.index.b_body), 3)))
    mujoco.mj_forward(w.model, w.data)
    qacc_kernel = w.data.qacc.copy()
    w.data.xfrc_applied[:] = 0
    qfrc = np.zeros(w.model.nv)
    for i in range(len(p)):
        mujoco.mj_applyFT(w.model, w.data, f[i], np.zeros(3), p[i], int(w.index.pt_body[i]), qfrc)
    w.data.qfrc_applied[:] = qfrc
    mujoco.mj_forward(w.model, w.data)
    np.testing.assert_allclose(qacc_kernel, w.data.qacc, rtol=1e-9, atol=1e-7)


def test_nearest_m_keeps_the_m_nearest_in_order_first_of_equals():
    # The re-ranked search's candidates (issue 27): the kernel's one pass against a stable sort,
    # on exact values with many ties (integers, halves: no rounding in either).
    rng = np.random.default_rng(0)
    for _ in range(300):
        N, m = int(rng.integers(1, 40)), int(rng.integers(1, 10))
        red = rng.integers(-3, 4, size=(3, N)).astype(float)
        q = rng.integers(-2, 3, size=3) * 0.5
        cands = np.zeros(m, np.int64)
        count = pk.nearest_m(q, red, (red * red).sum(0), np.zeros(N), cands)
        ref = np.argsort((red * red).sum(0) - 2 * q @ red, kind="stable")[:m]
        assert count == len(ref)
        np.testing.assert_array_equal(cands[:count], ref)
