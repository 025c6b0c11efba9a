"""Physics tracker speed: ms per character per frame at 120 Hz, characters in real time, MuJoCo step,
and the latency the tracker adds in a launched graph; the compiled path beside the numpy reference.

Prints, beside Shum & Ho's figures (C++/ODE on an i7-2600K: 0.65 ms per character per frame with a
0.10 ms database search; 2 characters shown) and the issue's targets (<= 0.3 ms; >= 8 characters in
real time on one core):

* one character tracking the synthetic walk at 120 Hz, a hand hidden so the posture database fills
  it every frame: ms per frame for what the node does per frame (conditioning with the database
  search, targets, simulation, state read-out, the outgoing PhysicsState/CharacterPose objects), the
  compiled kernels (``world.COMPILED``) beside the numpy reference (``reference.REFERENCE``) measured in the same run,
  and the ratio; then a second, profiled pass's breakdown per stage (thread CPU time per stage, with
  the profiling clock's own cost) and, with ``--cprofile``, cProfile's top functions;
* the posture search alone at 300 and 10 000 postures: the brute-force kernel, numpy's brute force
  and the k-d tree (ms per query; the database keeps the faster);
* N characters in one world (each with its own conditioning, database fill and read-out): ms per
  frame and per character, and how many fit in the 8.33 ms of a 120 Hz frame on one core;
* MuJoCo alone: mj_step of the one-character world, per step and per frame (2 substeps);
* a launched graph synthetic_character (120 Hz) -> physics_tracker -> this process, a process each and
  composed (`process:`, the hop in process): the tracker's added latency (its publish stamp minus the
  input's publish stamp), median and p99.
Every figure is this process's CPU time with the wall time and the load average beside it (the
machine is shared); the one-character run also prints its accuracy (MPJPE from the target, fall,
largest force and torque against their bounds).
Run: .venv/bin/python benchmarks/physics.py [--frames 600] [--graph-seconds 10] [--no-graph] [--cprofile]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import time

import mujoco
import numpy as np
from scipy.spatial import cKDTree

from _context import print_context
from _launched import launched_latencies_ms
from mocapgraph.jit import warm_all
from mocapgraph.messages import CharacterPose, PhysicsState
from mocapgraph.physics import posture_kernels as pk
from mocapgraph.physics.posture_db import PostureDB
from mocapgraph.physics.synthetic_targets import synthetic_targets
from mocapgraph.physics.control import tick
from mocapgraph.physics.reference import REFERENCE, ReferenceConditioner
from mocapgraph.physics.tracker import TargetConditioner
from mocapgraph.physics.world import COMPILED, PhysicsWorld, TrackerParams

RATE = 120.0
FRAME_MS = 1000.0 / RATE
KERNELS = ("mocapgraph.physics.controller_kernels", "mocapgraph.physics.posture_kernels",
           "mocapgraph.physics.state_kernels")
STAGES = ("conditioning", "database", "targets", "pins, dodge", "controller", "mj_step", "checks", "read-out",
          "messages")


def load() -> float:
    return os.getloadavg()[0]


def node_frame(w: PhysicsWorld, conds: list[TargetConditioner], inputs, t: float, quality,
               prof: dict[str, float] | None, messages: bool = True) -> None:
    """What the node does for one 120 Hz frame of every character (publishing aside)."""
    c0 = time.thread_time() if prof is not None else 0.0
    for k, (p, r, root) in enumerate(inputs):
        c = conds[k].condition(p, r, root, quality)
        if prof is not None:
            c0 = tick(prof, "conditioning", c0)
        w.set_target(k, c.positions, c.orientations, t)
        if prof is not None:
            c0 = tick(prof, "targets", c0)
    w.step(1.0 / RATE)
    if prof is not None:
        c0 = time.thread_time()
    pos, quat, err = w.geom_state()
    out = []
    for k in range(len(conds)):
        local, root = w.local_rotations(k)
        out.append((local, root, w.joint_positions(k)))
    if prof is not None:
        c0 = tick(prof, "read-out", c0)
    if not messages:
        return
    PhysicsState(sim_time_s=float(w.data.time), positions=pos, orientations=quat, tracking_error=err)
    for k, (local, root, jp) in enumerate(out):
        CharacterPose(character="c/physical", frame_number=1, root_position=root, local_rotations=local,
                      joint_positions=jp, joint_quality=np.ones(len(jp), dtype=np.int8))
    if prof is not None:
        tick(prof, "messages", c0)


def hidden_hand_inputs(clip, i: int, hand: int, offset=np.zeros(3)):
    p = clip.positions[i] + offset
    r = clip.local_rotations[i].copy()
    p[hand] = np.nan
    r[hand] = np.nan
    return p, r, clip.root[i] + offset


def one_character(clip, db, frames: int, compiled: bool, profiled: bool = False, messages: bool = True) -> dict:
    ch = clip.character
    w = PhysicsWorld([ch], params=TrackerParams(), kernels=COMPILED if compiled else REFERENCE)
    cond = (TargetConditioner if compiled else ReferenceConditioner)(ch, db)
    w.set_pose(0, clip.local_rotations[0], clip.root[0])
    hand = ch.index("HandRight")
    prof: dict[str, float] | None = {} if profiled else None
    w.profile = cond.profile = prof
    err = np.empty(frames)
    low = np.inf
    cpu = 0.0
    wall0 = time.perf_counter()
    for i in range(frames):
        inp = [hidden_hand_inputs(clip, i, hand)]
        t0 = time.process_time()
        node_frame(w, [cond], inp, clip.times[i], None, prof, messages)
        cpu += time.process_time() - t0
        sim = w.joint_positions(0)
        err[i] = np.linalg.norm(sim - clip.positions[i], axis=1).mean()
        low = min(low, sim[ch.root, 2])
    wall = time.perf_counter() - wall0
    if prof is not None:   # the database time was counted inside conditioning
        prof["conditioning"] -= prof.get("database", 0.0)
    return dict(ms=1e3 * cpu / frames, wall=1e3 * wall / frames, load=load(), mpjpe=1e3 * err.mean(),
                fall=low < 0.5 * w.bodies[0].standing_height, fmax=w.control.max_applied_force,
                bound=w.params.gains.max_force, tmax=w.control.max_applied_torque, tbound=w.params.gains.max_torque,
                resets=w.resets, stages={k: 1e3 * v / frames for k, v in (prof or {}).items()})


def many(clip, db, n: int, frames: int, compiled: bool) -> tuple[float, float]:
    ch = clip.character
    offs = [np.array([0.0, 2.5 * k, 0.0]) for k in range(n)]  # T-pose arms span 1.8 m
    w = PhysicsWorld([ch] * n, spawns=offs, params=TrackerParams(), kernels=COMPILED if compiled else REFERENCE)
    conds = [(TargetConditioner if compiled else ReferenceConditioner)(ch, db) for _ in range(n)]
    hand = ch.index("HandRight")
    for k in range(n):
        w.set_pose(k, clip.local_rotations[0], clip.root[0] + offs[k])
    t0, wall0 = time.process_time(), time.perf_counter()
    for i in range(frames):
        node_frame(w, conds, [hidden_hand_inputs(clip, i, hand, offs[k]) for k in range(n)], clip.times[i], None,
                   None)
    return 1e3 * (time.process_time() - t0) / frames, 1e3 * (time.perf_counter() - wall0) / frames


def clock_cost_us() -> float:
    """CPU us of one profiling tick (two thread_time calls and a dict update)."""
    prof: dict[str, float] = {}
    t = time.thread_time()
    t0 = time.process_time()
    for _ in range(20000):
        t = tick(prof, "x", t)
    return 1e6 * (time.process_time() - t0) / 20000


def search_ms(size: int, k: int = 7, trials: int = 400) -> dict[str, float]:
    """One-query nearest-posture search over ``size`` postures in k dimensions, ms per query."""
    rng = np.random.default_rng(size)
    red = rng.normal(0, 0.3, (size, k))
    sq = (red * red).sum(1)
    red_t = np.ascontiguousarray(red.T)
    search_t = np.ascontiguousarray(np.vstack([-2.0 * red.T, sq[None]]))
    dist = np.empty(size)
    tree = cKDTree(red)
    qs = red[rng.integers(0, size, trials)] + rng.normal(0, 0.02, (trials, k))
    q1 = np.ones(k + 1)
    out = {}
    for name, fn in (("kernel brute force", lambda q: pk.nearest(q, red_t, sq, dist)),
                     ("numpy brute force", lambda q: (q1.__setitem__(slice(0, k), q), np.argmin(q1 @ search_t))),
                     ("k-d tree", lambda q: tree.query(q, k=1))):
        fn(qs[0])
        t0 = time.process_time()
        for q in qs:
            fn(q)
        out[name] = 1e3 * (time.process_time() - t0) / trials
    return out


def mj_step_us(clip) -> float:
    w = PhysicsWorld([clip.character])
    w.set_pose(0, clip.local_rotations[0], clip.root[0])
    for i in range(60):
        w.set_target(0, clip.positions[i], clip.orientations[i], clip.times[i])
        w.step(1.0 / RATE)
    m, d = w.model, w.data
    d.xfrc_applied[:] = 0  # uncontrolled from here: a short span, measured before it falls far
    t0 = time.process_time()
    for _ in range(200):
        mujoco.mj_step(m, d)
    return 1e6 * (time.process_time() - t0) / 200


GRAPH = """\
nodes:
  - name: src
    type: synthetic_character
    params: {rate_hz: 120.0}
  - name: tracker
    type: physics_tracker
"""


def graph_latency(seconds: float, composed: bool = False) -> None:
    """The tracker's added latency in the launched graph; ``composed``: the source and the tracker in
    one process (``process: live``: the hop between them in process)."""
    graph = GRAPH.replace("    type: synthetic_character\n", "    type: synthetic_character\n    process: live\n") \
        .replace("    type: physics_tracker\n", "    type: physics_tracker\n    process: live\n") if composed else GRAPH
    v = np.asarray(launched_latencies_ms(graph, "character_pose", "sim_character_pose", seconds, warm_s=2.0))
    if not len(v):
        print("launched graph: no matched frames")
        return
    how = "composed in one process" if composed else "a process each"
    print(f"launched graph, synthetic_character 120 Hz -> physics_tracker ({how}), {len(v)} frames over {seconds:g} s:")
    print(f"  added latency (input publish -> simulated pose publish) median {np.median(v):.2f} ms, "
          f"p99 {np.percentile(v, 99):.2f} ms, max {v.max():.2f} ms (load {load():.2f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=600, help="frames per measurement")
    ap.add_argument("--graph-seconds", type=float, default=10.0)
    ap.add_argument("--no-graph", action="store_true")
    ap.add_argument("--cprofile", action="store_true", help="print cProfile's top functions of the compiled run")
    opts = ap.parse_args()
    warm_all(KERNELS)   # numba's first call in a process loads its cache: not a per-frame cost
    clip = synthetic_targets(17.0, 17.0 + opts.frames / RATE + 0.1)
    parts = [synthetic_targets(a, b, seed=1) for a, b in ((1, 17), (22, 37.5))]
    ch = clip.character
    db = PostureDB.build(ch.joint_names, ch.parents, np.concatenate([p.positions for p in parts]),
                         np.concatenate([p.local_rotations for p in parts]), min_ssd=0.005)
    db.choose_search()
    db.choose_search_compiled()
    n_clip = len(clip)
    print_context("0 for the tracked performer, 1 for the database's (synthetic_targets: SyntheticActor kiip_full_body "
                  "seed 0 / seed 1); PostureDB.choose_search probes: np.random.default_rng(0)",
                  "the synthetic performer on standard_20 at 120 Hz, the right hand hidden every frame",
                  f"tracked: performer 0, 17-{17.0 + opts.frames / RATE + 0.1:.2f} s (frames 2040-{2040 + n_clip - 1}), "
                  f"its first {opts.frames} frames ({min(opts.frames, 240)} for N characters, 60 then 200 "
                  f"uncontrolled steps for mj_step); database: performer 1, 1-17 s and 22-37.5 s (frames 120-2039, "
                  "2640-4499), not the tracked performer", section="tracking")
    print(f"machine: load average {load():.2f} on {os.cpu_count()} cores; times are this process's CPU time "
          "(the machine is shared: wall time would count other people's work)")
    runs = {c: one_character(clip, db, opts.frames, c) for c in (False, True)}
    ref, fast = runs[False], runs[True]
    print(f"one character, 120 Hz, database of {len(db)} postures (numpy path: {db.search}; compiled: "
          f"{db.search_compiled}), a hand filled every frame; per frame: conditioning with the database search, "
          "targets, simulation (2 substeps), state read-out, message objects:")
    for name, r in (("numpy reference", ref), ("compiled kernels", fast)):
        print(f"  {name:17s} {r['ms']:.3f} ms CPU per character per frame (Shum & Ho 0.65 ms: x{0.65 / r['ms']:.2f}; "
              f"target 0.3 ms), wall {r['wall']:.3f} ms (load {r['load']:.2f}); MPJPE from the target "
              f"{r['mpjpe']:.1f} mm, {'FELL' if r['fall'] else 'no fall'}, largest force {r['fmax']:.1f} N of "
              f"{r['bound']:.0f}, torque {r['tmax']:.2f} N·m of {r['tbound']:.0f}, resets {r['resets']}")
    print(f"  compiled / numpy: {fast['ms'] / ref['ms']:.3f} ({ref['ms'] / fast['ms']:.1f}x faster), same run")
    bare = {c: one_character(clip, db, opts.frames, c, messages=False) for c in (False, True)}
    print(f"  without building the outgoing message objects (the tracker's own work, as Shum & Ho count it): "
          f"numpy {bare[False]['ms']:.3f} ms, compiled {bare[True]['ms']:.3f} ms per character per frame "
          f"(x{0.65 / bare[True]['ms']:.2f} Shum & Ho; target 0.3 ms; load {bare[True]['load']:.2f})")
    clock = clock_cost_us()
    prof = {c: one_character(clip, db, opts.frames, c, profiled=True)["stages"] for c in (False, True)}
    print(f"  per stage, ms CPU per frame (a profiled pass: each stage carries ~{clock:.2f} us of clock per tick; "
          f"load {load():.2f}):")
    print(f"    {'stage':14s} {'numpy':>8s} {'compiled':>9s}")
    for st in STAGES:
        print(f"    {st:14s} {prof[False].get(st, 0.0):8.4f} {prof[True].get(st, 0.0):9.4f}")
    print(f"    {'sum':14s} {sum(prof[False].values()):8.4f} {sum(prof[True].values()):9.4f}")
    if opts.cprofile:
        w_prof = cProfile.Profile()
        w_prof.enable()
        one_character(clip, db, opts.frames, True)
        w_prof.disable()
        buf = io.StringIO()
        pstats.Stats(w_prof, stream=buf).sort_stats("tottime").print_stats(15)
        print("  cProfile of the compiled run (tottime; cProfile's own cost inflates small calls):")
        print("\n".join("    " + ln for ln in buf.getvalue().splitlines() if ln.strip()))
    print_context("300 and 10000 (np.random.default_rng(size): postures N(0, 0.3), queries)",
                  "generated reduced postures, k = 7", "400 queries per size: random postures + N(0, 0.02)",
                  section="posture search")
    for size in (300, 10000):
        r = search_ms(size)
        print(f"posture search over {size} postures (k = 7), ms per query: " +
              ", ".join(f"{k} {v:.4f}" for k, v in r.items()) + f" (load {load():.2f}; S&H 0.10 ms; target 0.05 ms)")
    for compiled in (False, True):
        fit = 0
        counts = (1, 2, 4, 8, 12, 16, 24, 30) if compiled else (1, 2, 4, 8, 12)   # 30: a world's most
        print(f"N characters in one world, {'compiled kernels' if compiled else 'numpy reference'} (each with "
              "conditioning, a database fill and read-out):")
        for n in counts:
            ms, wall = many(clip, db, n, min(opts.frames, 240), compiled)
            ok = ms <= FRAME_MS
            fit = n if ok else fit
            print(f"  {n:2d} characters: {ms:6.2f} ms per frame, {ms / n:.3f} ms per character "
                  f"({'real time' if ok else 'slower than real time'} at 120 Hz; wall {wall:.2f} ms, load {load():.2f})")
        print(f"  characters in real time at 120 Hz on one core: {fit} of those tried (target >= 8)")
    us = mj_step_us(clip)
    print(f"MuJoCo mj_step, one character: {us:.1f} us per step, {2 * us / 1000:.3f} ms per 120 Hz frame (2 steps; "
          f"load {load():.2f})")
    if not opts.no_graph:
        print_context("0 (the synthetic_character node's default performer seed)",
                      "a launched synthetic_character (the performer on standard_20 at 120 Hz, 17-37.5 s of its "
                      "session, looping) -> physics_tracker (no posture database: its default)",
                      f"frames matched on both topics, from 2 s after the first pair for {opts.graph_seconds:g} s, per run",
                      section="launched graph")
        graph_latency(opts.graph_seconds)
        graph_latency(opts.graph_seconds, composed=True)


if __name__ == "__main__":
    main()
