"""Settings of a physics world: MuJoCo's step, the controller's gains and bounds, pins, dodge (SI units)."""
from __future__ import annotations

from dataclasses import dataclass, field

from .controller import Gains


@dataclass
class TrackerParams:
    """Simulation and control settings (SI units)."""

    timestep: float = 1.0 / 240.0      # s, MuJoCo step (1/120 is unstable with these gains)
    gains: Gains = field(default_factory=Gains)
    body_mass: float = 70.0            # kg per character
    virtual_joints: bool = True        # pin supporting feet
    contact_height: float = 0.03       # m: a foot target this close to its rest height is on the floor
    contact_speed: float = 0.25        # m/s: ... and slower than this horizontally
    pin_slack: float = 0.05            # m: a pin lets go when its target is this far from it (a jump), and
                                       # a foot this far from its target is not pinned (it catches up first)
    pin_hold: float = 0.02             # m: a pinned foot stays put while its target is this close to it
                                       # (Kinect v2 feet jitter by 1-2 cm: 1 cm made pins follow the noise)
    pin_follow_speed: float = 0.18     # m/s: ... and beyond, follows it at most this fast horizontally
                                       # (1.5 mm a frame at 120 Hz: a foot pivoting in a turn)
    dodge: bool = False                # raise the forearms when a ball comes at the head
    dodge_horizon_s: float = 0.45      # s ahead a ball is seen coming
    joint_damping: float = 1.0         # N·m·s/rad in every ball joint
    max_target_speed: float = 6.0      # m/s: faster target velocities (jumps, glitches) are clipped
    gravity_compensation: float = 0.5  # fraction of each body's weight held up at its centre of mass
    foot_max_force: float = 40.0       # N, Eq 1 bound at the ankles and feet (<= gains.max_force)
    trunk_max_force: float = 60.0      # N, Eq 1 bound at the trunk's joints and the head (<= gains.max_force)
