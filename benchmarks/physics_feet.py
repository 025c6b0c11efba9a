"""Physics tracker feet: skating in contact and floor penetration, virtual joints on beside off.

Skating is #9's measure: the simulated foot point's horizontal displacement between consecutive
contact frames, contact taken from the input target (within ``contact_height`` of the foot's rest
height and slower than ``contact_speed`` horizontally, at this frame and the one before). Printed
per capture as mean / p95 / p99 / max mm per frame and the frames over 2 mm, with the largest
speed (mm/s: comparable across frame rates), floor penetration (lowest capsule point below the
floor) and resets, for:

* the synthetic performer's 20.5 s loop at 120 Hz (walk, reach, turn, walk back, kick, turn back;
  targets from ``synthetic_targets``), the turns also on their own;
* every ../shared/data/kinect2 recording (Kinect v2 gestures, 30 Hz) retargeted onto standard_20
  with the shipped mapping (the retargeter's batch path, default options), when present.
Then the CPU time and wall time per frame of each run, with the load average (the machine is shared).
Usage: python benchmarks/physics_feet.py [--no-kinect]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from mocapgraph.physics.synthetic_targets import synthetic_targets
from mocapgraph.physics.world import PhysicsWorld, TrackerParams

from _context import print_context

REPO = Path(__file__).resolve().parents[1]
SHARED = (REPO / ".." / "shared" / "data").resolve()
RECORDINGS = ["Ges01_wavehand", "Ges02_balancinghands", "Ges03_drawlines", "Ges04_comehere", "Ges05_demopoint"]


def track(character, local_rotations, root, positions, orientations, times, params: TrackerParams) -> dict:
    """Track one capture; per-frame simulated feet [F, 2, 3] m, lowest capsule point [F] m, costs."""
    w = PhysicsWorld([character], params=params)
    w.set_pose(0, local_rotations[0], root[0])
    feet = w.bodies[0].feet
    n = len(times)
    sim, lowest = np.empty((n, len(feet), 3)), np.empty(n)
    nominal = float(np.median(np.diff(times)))
    cpu, wall = time.process_time(), time.perf_counter()
    for i in range(n):
        w.set_target(0, positions[i], orientations[i], times[i])
        w.step(times[i + 1] - times[i] if i + 1 < n else nominal)
        sim[i] = w.joint_positions(0)[feet]
        lowest[i] = w.lowest_point(0)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    dt = np.diff(times)[:, None]
    tv = np.r_[np.zeros((1, len(feet))), np.linalg.norm(np.diff(positions[:, feet, :2], axis=0), axis=2) / dt]
    contact = (positions[:, feet, 2] < w.pins.rest_z[None] + params.contact_height) & (tv < params.contact_speed)
    both = contact.copy()
    both[0] = False
    both[1:] &= contact[:-1]
    step = np.r_[np.zeros((1, len(feet))), np.linalg.norm(np.diff(sim[:, :, :2], axis=0), axis=2)]
    speed = np.r_[np.zeros((1, len(feet))), step[1:] / dt]
    return dict(step=step, speed=speed, contact=both, lowest=lowest, resets=w.resets,
                cpu_ms=1000 * cpu / n, wall_ms=1000 * wall / n)


def line(name: str, r: dict, rows: np.ndarray | None = None) -> str:
    c = r["contact"] if rows is None else r["contact"] & rows[:, None]
    s, v = 1000 * r["step"][c], 1000 * r["speed"][c]
    pen = 1000 * max(0.0, -float(r["lowest"].min()))
    if not s.size:
        return f"  {name}: no contact frames"
    return (f"  {name}: {s.size} contact frames, skating mean {s.mean():.2f} mm/frame, p95 {np.percentile(s, 95):.2f}, "
            f"p99 {np.percentile(s, 99):.2f}, max {s.max():.2f} ({int((s > 2.0).sum())} over 2 mm; at most "
            f"{v.max():.0f} mm/s); penetration max {pen:.2f} mm; resets {r['resets']}; "
            f"{r['cpu_ms']:.3f} ms CPU, {r['wall_ms']:.3f} ms wall a frame (load {os.getloadavg()[0]:.1f})")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-kinect", action="store_true", help="the synthetic loop only")
    args = ap.parse_args()
    print(f"machine: load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    clip = synthetic_targets(17.0, 37.5, rate=120.0)
    turns = np.zeros(len(clip), dtype=bool)
    for a, b in ((25.0, 27.5), (35.0, 37.5)):
        turns[(clip.times >= a) & (clip.times < b)] = True
    print_context("0 (synthetic_targets' performer: SyntheticActor kiip_full_body seed 0)",
                  "the synthetic performer on standard_20 at 120 Hz (synthetic_targets)",
                  f"17-37.5 s of its session, frames {int(round(17 * 120))}-{int(round(37.5 * 120)) - 1} "
                  f"({len(clip)} frames); the turns: 25-27.5 s and 35-37.5 s ({int(turns.sum())} frames)",
                  section="synthetic")
    print("synthetic performer, 20.5 s loop at 120 Hz:")
    for vj in (True, False):
        r = track(clip.character, clip.local_rotations, clip.root, clip.positions, clip.orientations, clip.times,
                  TrackerParams(virtual_joints=vj))
        tag = "virtual joints on " if vj else "virtual joints off"
        print(line(tag, r))
        print(line(tag + ", the turns", r, turns))
    if args.no_kinect or not (SHARED / "kinect2").is_dir():
        return 0
    from mocapgraph.formats.kinect_csv import read_kinect_csv
    from mocapgraph.formats.mapping_file import load_mapping
    from mocapgraph.retarget.character import standard_20
    from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
    from mocapgraph.retarget.source import kinect_source, observed_bone_lengths
    ch = standard_20(1.75)
    mapping = load_mapping("kinect_v2_standard_20")
    for name in RECORDINGS:
        path = SHARED / "kinect2" / f"{name}.csv"
        if not path.exists():
            continue
        trial = read_kinect_csv(path, ground="feet")
        print_context(None, f"real Kinect v2 recording {path}", f"all {len(trial.timestamps_ns)} frames",
                      section=name)
        # the performer's own bone lengths, as the retargeter node and `mocapgraph retarget` take them
        tracked = np.where((trial.tracking_state == 2)[..., None], trial.positions, np.nan)
        src = kinect_source(trial.names, trial.parents, bone_lengths=observed_bone_lengths(tracked, trial.parents))
        res = Retargeter(ch, mapping, src, RetargetOptions()).process(trial.positions, trial.tracking_state == 2)
        pos, ori = ch.forward_kinematics(res.local_rotations, res.root_positions)
        t = (np.asarray(trial.timestamps_ns) - trial.timestamps_ns[0]) * 1e-9
        toes = [ch.index("FootLeft"), ch.index("FootRight")]
        print(f"{name} (Kinect v2 onto standard_20, {len(t)} frames at {(len(t) - 1) / t[-1]:.0f} Hz; the "
              f"retargeted toes {100 * np.nanmedian(pos[:, toes, 2]):.0f} cm from the floor, median):")
        for vj in (True, False):
            r = track(ch, res.local_rotations, res.root_positions, pos, ori, t, TrackerParams(virtual_joints=vj))
            print(line("virtual joints on " if vj else "virtual joints off", r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
