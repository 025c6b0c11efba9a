"""The physical character tracks the synthetic performer (Shum & Ho section 6), measured.

One 20.5 s run of the performance loop (walk, reach, turn, walk back, kick, turn back) per setting,
shared by the tests of this module: targets are ``standard_20`` driven by the synthetic actor, the
ground truth is the actor's own joint centres (a body we did not make the character from).
"""
from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mocapgraph.retarget.character import standard_20
from mocapgraph.physics.body import character_body
from mocapgraph.physics.controller import Gains
from mocapgraph.physics.synthetic_targets import synthetic_targets
from mocapgraph.physics.reference import apply_wrenches
from mocapgraph.physics.world import PhysicsWorld, TrackerParams

RATE = 120.0
PERF = (17.0, 37.5)


@pytest.fixture(scope="module")
def clip():
    return synthetic_targets(*PERF, rate=RATE)


def run(clip, params: TrackerParams):
    """Track the whole clip; per-frame arrays of what the tests look at."""
    w = PhysicsWorld([clip.character], params=params)
    w.set_pose(0, clip.local_rotations[0], clip.root[0])
    feet = w.bodies[0].feet
    caps = np.array([i for i, n in enumerate(w.index.geom_names) if n.startswith("c0/")])
    n = len(clip)
    sim = np.empty((n, clip.character.n_joints, 3))
    lowest = np.empty(n)
    forces, torques, foot_forces = np.empty(n), np.empty(n), np.empty(n)
    feet_pts = np.r_[feet, clip.character.parents[feet]]
    for i in range(n):
        w.set_target(0, clip.positions[i], clip.orientations[i], clip.times[i])
        w.step(1.0 / RATE)
        sim[i] = w.joint_positions(0)
        fn = np.linalg.norm(w.control.last_forces, axis=1)
        forces[i] = fn.max()
        foot_forces[i] = fn[feet_pts].max()
        torques[i] = np.linalg.norm(w.control.last_torques, axis=1).max()
        g = w.index.geom_ids[caps]
        zc = w.data.geom_xpos[g, 2]
        axz = np.abs(w.data.geom_xmat[g].reshape(-1, 3, 3)[:, 2, 2])
        lowest[i] = (zc - axz * w.model.geom_size[g, 1] - w.model.geom_size[g, 0]).min()
    tv = np.r_[np.zeros((1, len(feet))),
               np.linalg.norm(np.diff(clip.positions[:, feet, :2], axis=0), axis=2) * RATE]
    contact = (clip.positions[:, feet, 2] < w.pins.rest_z[None] + params.contact_height) & (tv < params.contact_speed)
    # skating (#9): horizontal foot displacement between consecutive contact frames
    both = contact.copy()
    both[0] = False
    both[1:] &= contact[:-1]
    step = np.r_[np.zeros((1, len(feet))), np.linalg.norm(np.diff(sim[:, feet, :2], axis=0), axis=2)]
    return dict(world=w, sim=sim, lowest=lowest, forces=forces, torques=torques, foot_forces=foot_forces,
                skate=step[both], step=step, contact=both, resets=w.resets)


@pytest.fixture(scope="module")
def pinned(clip):
    return run(clip, TrackerParams(virtual_joints=True))


@pytest.fixture(scope="module")
def free_feet(clip):
    # the whole loop again (about 1 s of CPU on the compiled path): the same frames compared
    return run(clip, TrackerParams(virtual_joints=False))


def test_tracks_walk_reach_turn_kick_within_30mm(clip, pinned):
    err = np.linalg.norm(pinned["sim"] - clip.positions, axis=2)
    truth = np.linalg.norm(pinned["sim"] - clip.truth, axis=2)
    print(f"\nMPJPE from the target {1000 * err.mean():.1f} mm, from the synthetic ground truth "
          f"{1000 * truth.mean():.1f} mm (target vs truth {1000 * np.linalg.norm(clip.positions - clip.truth, axis=2).mean():.1f} mm); "
          f"worst joint {1000 * err.mean(0).max():.1f} mm")
    clips = {"walk": (17, 22), "reach": (22, 25), "turn": (25, 27.5), "walk back": (27.5, 32.5),
             "kick": (32.5, 35), "turn back": (35, 37.5)}
    for name, (a, b) in clips.items():
        s = slice(int((a - PERF[0]) * RATE), int((b - PERF[0]) * RATE))
        print(f"  {name:10s} {1000 * err[s].mean():5.1f} mm")
        assert err[s].mean() <= 0.030, name
    assert err.mean() <= 0.030


def test_no_fall_lengths_kept_forces_bounded(clip, pinned):
    w = pinned["world"]
    root = pinned["sim"][:, clip.character.root, 2]
    standing = w.bodies[0].standing_height
    assert root.min() > 0.5 * standing, f"fell: root down to {root.min():.3f} m of {standing:.3f}"
    par = clip.character.parents
    kids = np.flatnonzero(par >= 0)
    lengths = np.linalg.norm(pinned["sim"][:, kids] - pinned["sim"][:, par[kids]], axis=2)
    drift = np.abs(lengths - clip.character.bone_lengths[kids]).max()
    print(f"\nsegment length drift {1000 * drift:.3f} mm; largest force applied {pinned['forces'].max():.1f} N "
          f"(bound {w.params.gains.max_force}), torque {pinned['torques'].max():.2f} N·m (bound {w.params.gains.max_torque})")
    assert drift <= 0.001
    assert pinned["forces"].max() <= w.params.gains.max_force + 1e-9
    assert pinned["foot_forces"].max() <= w.params.foot_max_force + 1e-9
    assert pinned["torques"].max() <= w.params.gains.max_torque + 1e-9
    assert w.control.max_applied_force <= w.params.gains.max_force + 1e-9
    assert pinned["resets"] == 0


def test_feet_with_and_without_virtual_joints(pinned, free_feet):
    """#15: with virtual joints on, skating in contact at most 2 mm a frame (every frame, the turns'
    pivots included) and floor penetration at most 5 mm; the same figures printed with them off."""
    turns = np.zeros(len(pinned["step"]), dtype=bool)
    for a, b in ((25.0, 27.5), (35.0, 37.5)):
        turns[int((a - PERF[0]) * RATE):int((b - PERF[0]) * RATE)] = True
    for name, r in (("virtual joints on ", pinned), ("virtual joints off", free_feet)):
        s = 1000 * r["skate"]
        t = 1000 * r["step"][r["contact"] & turns[:, None]]
        pen = 1000 * np.maximum(0.0, -r["lowest"])
        print(f"\n{name}: skating over {s.size} consecutive contact frames mean {s.mean():.2f} mm/frame "
              f"(p95 {np.percentile(s, 95):.2f}, p99 {np.percentile(s, 99):.2f}, max {s.max():.2f}; "
              f"{int((s > 2.0).sum())} frames over 2 mm; in the turns mean {t.mean():.2f}, max {t.max():.2f}); "
              f"floor penetration p95 {np.percentile(pen, 95):.2f} mm, max {pen.max():.2f} mm")
    assert pinned["contact"].sum() > 1000 and (pinned["contact"] & turns[:, None]).sum() > 300
    skate = 1000 * pinned["skate"]
    assert skate.max() <= 2.0, f"skating {skate.max():.2f} mm/frame at frame(s) " \
        f"{np.flatnonzero((1000 * pinned['step'] > 2.0) & pinned['contact']).tolist()}"
    assert skate.mean() <= 0.5
    # the pins do something: without them the feet skate more, on average and at worst
    free = 1000 * free_feet["skate"]
    assert skate.mean() < free.mean() and skate.max() < free.max()
    # the 5 mm, heel and toe strikes included (the feet's own force bound keeps them soft)
    assert 1000 * np.maximum(0.0, -pinned["lowest"]).max() <= 5.0


def test_body_masses_and_mjcf_file(tmp_path):
    ch = standard_20(1.75)
    w = PhysicsWorld([ch], params=TrackerParams(body_mass=82.0))
    m = w.model
    bodies = w.index.b_body
    assert m.body_mass[bodies].sum() == pytest.approx(82.0, rel=1e-6)
    # de Leva: both thighs 28.3 % of body mass, sitting on the hip bodies
    thigh = m.body_mass[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "c0/HipLeft")]
    assert thigh == pytest.approx(0.1416 * 82.0, rel=1e-6)
    path = tmp_path / "body.xml"
    path.write_text(w.xml)
    again = mujoco.MjModel.from_xml_path(str(path))
    assert again.nbody == m.nbody and again.ngeom == m.ngeom
    assert again.nq == 7 + 4 * (len(character_body(ch, 0).body_joints) - 1)


def test_forces_through_xfrc_equal_mj_applyFT_at_the_joints(clip):
    """Our per-body wrench (force at the joint + its moment about the CoM) moves the model exactly
    as mj_applyFT at each joint point does."""
    w = PhysicsWorld([clip.character])
    w.set_pose(0, clip.local_rotations[300], clip.root[300])
    rng = np.random.default_rng(3)
    w.data.qvel[:] = rng.normal(0, 0.5, w.model.nv)
    mujoco.mj_forward(w.model, w.data)
    p = w.readout.point_positions()
    f = rng.normal(0, 50, p.shape)
    apply_wrenches(w.control.sim, w.control.points, f, w.index.b_body, np.zeros((len(w.index.b_body), 3)))
    mujoco.mj_forward(w.model, w.data)
    qacc_ours = w.data.qacc.copy()
    w.data.xfrc_applied[:] = 0
    qfrc = np.zeros(w.model.nv)
    for i in range(len(p)):
        mujoco.mj_applyFT(w.model, w.data, f[i], np.zeros(3), p[i], int(w.index.pt_body[i]), qfrc)
    w.data.qfrc_applied[:] = qfrc
    mujoco.mj_forward(w.model, w.data)
    np.testing.assert_allclose(qacc_ours, w.data.qacc, rtol=1e-9, atol=1e-7)


def test_point_velocities_match_mujoco_jacobians(clip):
    w = PhysicsWorld([clip.character])
    w.set_pose(0, clip.local_rotations[500], clip.root[500])
    w.data.qvel[:] = np.random.default_rng(1).normal(0, 1.0, w.model.nv)
    mujoco.mj_forward(w.model, w.data)
    p = w.readout.point_positions()
    v = w.readout.point_velocities(p)
    jacp = np.zeros((3, w.model.nv))
    for i in range(len(p)):
        mujoco.mj_jac(w.model, w.data, jacp, None, p[i], int(w.index.pt_body[i]))
        np.testing.assert_allclose(v[i], jacp @ w.data.qvel, atol=1e-9)
    # and the simulated joints sit on the target pose we put the body in, raised onto the floor
    # (this frame's heel capsule cuts 43 mm into it: set_pose never starts a body in the floor)
    lift = p[w.index.point_slice[0]][clip.character.root, 2] - clip.positions[500, clip.character.root, 2]
    np.testing.assert_allclose(p[w.index.point_slice[0]] - [0.0, 0.0, lift], clip.positions[500], atol=1e-9)
    assert 0.0 < lift < 0.05 and abs(w.lowest_point(0)) < 1e-9


def test_absurd_gains_are_refused_or_bounded():
    with pytest.raises(ValueError, match="kp"):
        Gains(kp=float("nan")).check()


def test_physics_mjcf_command_writes_a_model_mujoco_opens(tmp_path):
    import sys

    from graph_helpers import run_concurrently

    out = tmp_path / "body.xml"
    mjcf = [sys.executable, "-m", "mocapgraph", "physics", "mjcf", "standard_20"]
    # the good and the refused command at once (their interpreters' start-up shares the cores;
    # the refused one is pointed at a file of its own so that it cannot race the good one)
    r, bad = run_concurrently([mjcf + ["-o", str(out), "--stage", "claro_pole"],
                               mjcf + ["-o", str(tmp_path / "bad.xml"), "--stage", "nosuch"]], timeout=120)
    assert r.returncode == 0, r.stderr
    m = mujoco.MjModel.from_xml_path(str(out))
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "stage/cube") >= 0
    assert bad.returncode == 2 and "nosuch" in bad.stderr and "Traceback" not in bad.stderr


def test_a_pose_into_the_floor_is_raised_onto_it_and_tracked_without_blowing_up(clip):
    """A source whose floor is 20 cm above ours (retargeted Kinect v2 gestures put the toes 16-27
    cm under it): set_pose raises the body onto the floor (it started inside it and MuJoCo's
    solver reset the state on the first step), and targets under the floor are tracked on it."""
    w = PhysicsWorld([clip.character])
    down = np.array([0.0, 0.0, -0.2])
    w.set_pose(0, clip.local_rotations[0], clip.root[0] + down)
    low = w.lowest_point(0)
    w2 = PhysicsWorld([clip.character])
    w2.set_pose(0, clip.local_rotations[0], clip.root[0])
    print(f"\nlowest capsule point after set_pose 20 cm down: {1000 * low:.3f} mm (in the pose as given "
          f"{1000 * (w2.lowest_point(0) - 0.2):.1f} mm); root raised to {w.joint_positions(0)[clip.character.root, 2]:.3f} m")
    assert abs(low) < 1e-9
    assert w.joint_positions(0)[clip.character.root, 2] > clip.root[0, 2] - 0.2 + 0.1
    lowest = []
    for i in range(int(1.5 * RATE)):
        w.set_target(0, clip.positions[i] + down, clip.orientations[i], clip.times[i])
        w.step(1.0 / RATE)
        lowest.append(w.lowest_point(0))
    assert w.resets == 0 and np.isfinite(w.data.qpos).all()
    assert min(lowest) > -0.005
