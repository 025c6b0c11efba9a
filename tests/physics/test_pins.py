"""Foot pins (virtual joints, Shum & Ho 6.1) on a standing body: a pivoting foot turns with its
target at a bounded rate and stays pinned while its target is on the floor; lifting or jumping
lets go. Real MuJoCo worlds, both the compiled path and the numpy reference."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapgraph.retarget.character import standard_20
from mocapgraph.physics.reference import REFERENCE
from mocapgraph.physics.world import COMPILED, PhysicsWorld, TrackerParams

RATE = 120.0


@pytest.mark.parametrize("compiled", [True, False])
def test_a_pivoting_foot_follows_its_target_at_a_bounded_rate_and_lets_go_when_lifted(compiled):
    ch = standard_20(1.75)
    prm = TrackerParams()
    w = PhysicsWorld([ch], params=prm, kernels=COMPILED if compiled else REFERENCE)
    w.set_pose(0, np.tile([1.0, 0, 0, 0], (ch.n_joints, 1)), ch.rest_pose()[0][ch.root])
    pos, rot = ch.rest_pose()
    toe, ankle = ch.index("FootRight"), ch.index("AnkleRight")
    k = list(w.bodies[0].feet).index(toe)
    t = 0.0

    def frame(p):
        nonlocal t
        w.set_target(0, p, rot, t)
        w.step(1.0 / RATE)
        t += 1.0 / RATE
        return w.joint_positions(0)[toe].copy(), w.data.mocap_pos[w.pins.mocap[k]].copy(), bool(w.pins.on[k])

    for _ in range(int(0.5 * RATE)):                       # standing still: both feet pinned
        frame(pos)
    assert w.pins.on.all()
    # the toe pivots about the ankle at 0.2 m/s (over the follow speed, under the contact speed) for
    # 0.75 s, 15 cm of arc: it stays on the floor, so it stays pinned and its pin follows it
    arm = pos[toe] - pos[ankle]
    omega = 0.2 / np.linalg.norm(arm[:2])
    sim, pins, on = [], [], []
    p = pos.copy()
    for i in range(1, int(0.75 * RATE) + 1):
        p = pos.copy()
        p[toe] = pos[ankle] + Rotation.from_rotvec([0, 0, omega * i / RATE]).apply(arm)
        s, a, o = frame(p)
        sim.append(s), pins.append(a), on.append(o)
    for _ in range(int(0.75 * RATE)):                      # the target stops: the pin catches up
        s, a, o = frame(p)
        sim.append(s), pins.append(a), on.append(o)
    sim, pins = np.array(sim), np.array(pins)
    step = 1000 * np.linalg.norm(np.diff(sim[:, :2], axis=0), axis=1)
    pin_step = np.linalg.norm(np.diff(pins[:, :2], axis=0), axis=1)
    left = np.linalg.norm(p[toe, :2] - pins[-1, :2])
    print(f"\n{'compiled' if compiled else 'numpy'}: pivoting toe skates {step.mean():.2f} mm/frame mean, "
          f"max {step.max():.2f}; pin moved {pins[-1, 0] - pins[0, 0]:+.3f}, {pins[-1, 1] - pins[0, 1]:+.3f} m, "
          f"at most {1000 * pin_step.max():.2f} mm a frame; ends {1000 * left:.1f} mm from the target")
    assert all(on), "the pin let go while its target stayed on the floor"
    assert pin_step.max() <= prm.pin_follow_speed / RATE + 1e-9
    assert pin_step.max() >= 0.99 * prm.pin_follow_speed / RATE     # it did follow, at its bounded rate
    assert step.max() <= 2.0
    assert left <= prm.pin_hold + 1e-9                              # and came to rest by the target
    assert np.linalg.norm(sim[-1, :2] - pins[-1, :2]) < 0.005        # the foot is where its pin is
    # lifting the target 5 cm lets go at once; back on the floor it pins where the foot is
    up = p.copy()
    up[toe, 2] += 0.05
    s, _, o = frame(up)
    assert not o
    _, a, o = frame(p)
    assert o and np.linalg.norm(a[:2] - s[:2]) < 1e-9
    # a target that jumps 30 cm along the floor lets go (it is moving, then too far to hold)
    jump = p.copy()
    jump[toe, 0] += 0.3
    assert not frame(jump)[2]
    assert not frame(jump)[2]                             # and is not re-pinned far from its foot
