"""Retargeting benchmark: live frames/s, batch frames/s, and the latency the node adds in a graph.

Prints:
- live: one frame at a time (what the node does), the synthetic actor (1 mm noise, solved) onto
  standard_20 (20 joints), with and without foot planting; frames/s and us/frame of the compiled
  kernel (kernels), the numpy one-frame path and the batched path, beside a baseline
  measured in the same run: one Character.forward_kinematics call per frame. Target: at least
  10 000 frames/s (under 0.1 ms a frame) on one core.
- node path: what the retargeter node does per ActorPose (decode, Retargeter.process_actor: the point
  layout, masks, retargeting and bone-follow flags in one compiled call, CharacterPose, encode) in this
  process, CPU us/frame and wall p50/p99 (the node's own added latency, no transport).
- batch: whole trials in one call (the `mocapgraph retarget` path): the synthetic performance onto
  standard_20, CMU 131_01 onto Mixamo (70 joints, fingers), frames/s.
- hop reference: one frame between two Python processes at 240 Hz, raw pyzmq and mocapgraph nodes
  (benchmarks/bus.py's measurement) in the same run: what the machine itself gives a hop.
- graph: synthetic actor at 240 Hz -> calibration (model file) -> frame solver -> retargeter ->
  bag recorder, launched; per frame the CharacterPose publish stamp minus the ActorPose publish
  stamp of the same frame (transport + retargeting): p50, p99, max in ms, and the breakdown: the
  hop solver -> retargeter from the node's own edge statistics (recorded diagnostics), the rest,
  and the node process's CPU per frame. Target p99 <= 0.3 ms. Three runs: a process per node, the
  same with keep_up, and the solver and retargeter composed in one process (``process:``: the hop
  between them in process, the reader and the recorder in their own processes).
- shipped graph: retarget_optical.yaml as a lab runs it (240 Hz onto standard_20, the viewer on at its
  shipped nice 10, pipeline_process:=live), this process subscribed to actor_pose and character_pose:
  the same added latency, p50, p99, max.
- the machine's load average while it ran (the figures depend on it).

Usage: python benchmarks/retarget.py [--live-frames 3000] [--graph-s 10] [--no-graph | --graph-only]
"""
from __future__ import annotations

import argparse
import functools
import gc
import os
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SHARED = (REPO / ".." / "shared" / "data").resolve()
sys.path.insert(0, str(REPO / "benchmarks"))
from _context import print_context  # noqa: E402

ACTOR_SEED = "0 (SyntheticActor kiip_full_body seed 0, 1 mm noise)"


def _actor_data() -> str:
    """What the solved synthetic actor of _solved_actor is: its calibration and performance frames."""
    cap = _solved_actor()[0]
    perf = cap.phase_slice("performance")
    return (f"the synthetic actor (kiip_full_body, {cap.rate:g} Hz), calibrated on frames 0-{cap.phases['gym'][1] - 1} "
            f"(base and gym), its performance (frames {perf.start}-{perf.stop - 1}) solved by FrameSolver")


@functools.lru_cache(maxsize=1)
def _solved_actor():
    from mocapgraph.kinematics.calibration.calibrate import calibrate
    from mocapgraph.retarget.source import optical_points, optical_source
    from mocapgraph.kinematics.solving.solver import FrameSolver
    from mocapgraph.kinematics.synthetic.actor import CaptureOptions, SyntheticActor
    cap = SyntheticActor("kiip_full_body", options=CaptureOptions(noise_mm=1.0)).capture()
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    perf = cap.phase_slice("performance")
    res = FrameSolver(model, rate_hz=cap.rate).solve(cap.markers[perf])
    src = optical_source(model.joint_names, model.joint_parent, model.joint_limbs, model.limb_names, model.joint_base)
    actor = tuple(np.ascontiguousarray(a) for a in (res.joints, res.joint_quality.astype(np.int8), res.limb_rotation,
                                                     res.limb_quality.astype(np.int8)))
    return cap, model, src, optical_points(res.joints, model.joint_names), res.limb_rotation, res.limb_quality > 0, \
        cap.times[perf], actor


def bench_live(n: int) -> None:
    from mocapgraph.retarget.character import standard_20
    from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
    from mocapgraph.retarget.mapping import derive_mapping
    from mocapgraph.retarget.live_numpy import NumpyFrame
    cap, model, src, pts, rot, rok, t, actor = _solved_actor()
    ch = standard_20(1.75)
    m = derive_mapping(ch, src)
    n = min(n, len(pts))
    print_context(ACTOR_SEED, _actor_data(), f"the first {n} performance frames one at a time (the first 50 also run "
                  "once untimed, to warm up)", section="live")
    q = np.tile([1.0, 0, 0, 0], (ch.n_joints, 4 // 4))
    t0 = time.process_time()
    for f in range(n):
        ch.forward_kinematics(q[None], pts[f:f + 1, -1])
    base = (time.process_time() - t0) / n
    print("(CPU time of this process, i.e. one core, so that other load on the machine does not count)")
    print(f"live, one frame at a time, {n} frames of the solved synthetic actor onto standard_20 (20 joints):")
    print(f"  baseline (one forward_kinematics call per frame):    {1e6 * base:8.1f} us/frame CPU  {1 / base:9.0f} frames/s")
    pts, rot, rok = np.ascontiguousarray(pts), np.ascontiguousarray(rot), np.ascontiguousarray(rok)
    for planting in (False, True):
        per = {}
        # the batched path one frame at a time, the numpy one-frame path (the kernel's reference), the
        # compiled kernel (what the node runs)
        for what, kw in (("batched path, F = 1   ", dict(live=False)), ("numpy one-frame path  ", dict(frame_path=NumpyFrame)),
                         ("compiled kernel       ", {})):
            rt = Retargeter(ch, m, src, RetargetOptions(foot_planting=planting), **kw)
            for f in range(50):  # warm
                rt.process(pts[f:f + 1], None, rot[f:f + 1], rok[f:f + 1], t[f:f + 1])
            rt.reset()
            t0, w0 = time.process_time(), time.perf_counter()
            for f in range(n):
                rt.process(pts[f:f + 1], None, rot[f:f + 1], rok[f:f + 1], t[f:f + 1])
            dt, dw = (time.process_time() - t0) / n, (time.perf_counter() - w0) / n
            per[what] = dt
            ratios = f"{dt / base:.2f}x the baseline" + "".join(
                f", {per[k] / dt:.1f}x faster than the {k.strip()}" for k in per if k != what)
            print(f"  {what} planting {'on ' if planting else 'off'}: {1e6 * dt:8.1f} us/frame CPU ({1e6 * dw:7.1f} wall)  "
                  f"{1 / dt:9.0f} frames/s  ({ratios})")
        # the node's call: the actor's own arrays, point layout and masks in the same compiled call
        rt = Retargeter(ch, m, src, RetargetOptions(foot_planting=planting))
        jp, jq, lr, lq = actor
        for f in range(50):
            rt.process_actor(jp[f], jq[f], lr[f], lq[f], t[f])
        rt.reset()
        t0, w0 = time.process_time(), time.perf_counter()
        for f in range(n):
            rt.process_actor(jp[f], jq[f], lr[f], lq[f], t[f])
        dt, dw = (time.process_time() - t0) / n, (time.perf_counter() - w0) / n
        print(f"  actor frame (the node's call) planting {'on ' if planting else 'off'}: {1e6 * dt:8.1f} us/frame CPU "
              f"({1e6 * dw:7.1f} wall)  {1 / dt:9.0f} frames/s  ({dt / base:.2f}x the baseline)")
        print(f"  (target >= 10000 frames/s, < 100 us a frame; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())})")


def bench_node_path(n: int) -> None:
    """What the retargeter node does per ActorPose, in this process: decode the frames off the
    wire format, the node's one call (Retargeter.process_actor into its one-frame buffers), its one
    CharacterPose (the buffers' arrays; the frame number set), encode. (The launched graph below
    adds transport and scheduling on a loaded machine.)"""
    from mocapgraph.formats.retarget_setup import build, source_from_model
    from mocapgraph.retarget.retargeter import RetargetOptions
    from mocapgraph.kinematics.solving.solver import FrameSolver
    from mocapgraph.messages import ActorPose, CharacterPose
    from mocapgraph.messages.codec import decode_envelope, decode_payload, encode, header_capture_ns
    cap, model, src, pts, rot, rok, t, actor = _solved_actor()
    perf = cap.phase_slice("performance")
    res = FrameSolver(model, rate_hz=cap.rate).solve(cap.markers[perf])
    n = min(n, len(pts))
    wire = []
    print_context(ACTOR_SEED, _actor_data(), f"the first {n} performance frames, encoded as ActorPose; wall "
                  "latencies from frame 50 on", section="node path")
    for f in range(n):
        msg = ActorPose(actor="a", frame_number=f, joint_positions=res.joints[f], joint_quality=res.joint_quality[f],
                        limb_orientations=res.limb_rotation[f], limb_quality=res.limb_quality[f],
                        limb_visible_markers=np.zeros(len(model.limb_names), np.int16))
        wire.append([bytes(x) for x in encode("actor_pose", msg, f, int(t[f] * 1e9), "solver")])
    print(f"node path in this process ({n} ActorPose frames: decode, process_actor, CharacterPose, encode):")
    for planting in (False, True):
        setup = build("standard_20", None, source_from_model(model.joint_names, model.joint_parent, model.joint_limbs,
                                                              model.limb_names, model.joint_base),
                      RetargetOptions(foot_planting=planting))
        rt = setup.retargeter
        buf = rt.actor_buffers()
        out = CharacterPose(character="standard_20", frame_number=0, root_position=buf.root_positions[0],
                            local_rotations=buf.local_rotations[0], joint_positions=buf.joint_positions[0],
                            joint_quality=buf.joint_quality[0])
        lat = np.empty(n)
        gc.collect()
        gc.freeze()   # as Node.run does before serving: start-up objects are not scanned per message
        t0 = header_capture_ns(wire[0][1])
        c0 = time.process_time()
        for f, frames in enumerate(wire):
            w0 = time.perf_counter_ns()
            env = decode_envelope(frames)
            msg = decode_payload(ActorPose, env, frames)
            rt.process_actor(msg.joint_positions, msg.joint_quality, msg.limb_orientations, msg.limb_quality,
                             (env.capture_ns - t0) * 1e-9, buf)
            out.frame_number = msg.frame_number
            encode("character_pose", out, f, env.capture_ns, "retargeter")
            lat[f] = (time.perf_counter_ns() - w0) * 1e-3
        cpu = (time.process_time() - c0) / n
        lat = lat[50:]
        print(f"  planting {'on ' if planting else 'off'}: CPU {1e6 * cpu:7.1f} us/frame; wall p50 {np.percentile(lat, 50):7.1f} us, "
              f"p99 {np.percentile(lat, 99):7.1f} us, max {lat.max():7.1f} us (target: CPU well under 150 us; load average "
              f"{' '.join(f'{x:.1f}' for x in os.getloadavg())})")


def bench_batch() -> None:
    from mocapgraph.formats.bvh_file import bvh_to_skeleton, read_bvh
    from mocapgraph.formats.character_file import load_character
    from mocapgraph.retarget.character import standard_20
    from mocapgraph.retarget.retargeter import RetargetOptions, Retargeter
    from mocapgraph.retarget.mapping import derive_mapping
    from mocapgraph.retarget.source import skeleton_source
    cap, model, src, pts, rot, rok, t, actor = _solved_actor()
    print_context(ACTOR_SEED, _actor_data(), f"every performance frame ({len(pts)}), one call", section="batch, synthetic")
    print("batch, a whole trial in one call:")
    for planting in (False, True):
        ch = standard_20(1.75)
        rt = Retargeter(ch, derive_mapping(ch, src), src, RetargetOptions(foot_planting=planting))
        t0 = time.process_time()
        rt.process(pts, None, rot, rok, t)
        dt = time.process_time() - t0
        print(f"  synthetic performance ({len(pts)} frames) onto standard_20, planting {'on ' if planting else 'off'}: "
              f"{len(pts) / dt:9.0f} frames/s")
    bvh = SHARED / "bvh/cmu/131_01.bvh"
    if bvh.exists():
        motion = read_bvh(bvh)
        print_context(None, f"the real capture {bvh}", f"every frame ({motion.n_frames}), one call",
                      section="batch, CMU 131_01")
        tr = bvh_to_skeleton(motion)
        rest = motion.rest_positions()
        p = tr.parents
        offs = np.where((p >= 0)[:, None], rest - rest[np.maximum(p, 0)], rest)
        s2 = skeleton_source(tr.names, p, offs, has_orientations=True)
        mix = load_character("mixamo")
        for planting in (False, True):
            rt = Retargeter(mix, derive_mapping(mix, s2), s2, RetargetOptions(foot_planting=planting))
            t0 = time.process_time()
            rt.process(tr.positions, None, tr.orientations, None, np.arange(motion.n_frames) / motion.rate_hz)
            dt = time.process_time() - t0
            print(f"  CMU 131_01 ({motion.n_frames} frames) onto Mixamo (70 joints), planting {'on ' if planting else 'off'}: "
                  f"{motion.n_frames / dt:9.0f} frames/s")


def bench_graph(seconds: float, keep_up: bool = False, composed: bool = False) -> None:
    from mocapgraph.bag.reader import BagReader
    from mocapgraph.kinematics.calibration.calibrate import calibrate
    from mocapgraph.kinematics.model import save_model
    from mocapgraph.kinematics.synthetic.actor import SyntheticActor
    tmp = Path(tempfile.mkdtemp(prefix="retarget_bench_"))
    cap = SyntheticActor("kiip_full_body", rate=240.0).capture(0, int(240 * 20))
    model = calibrate(cap.skeleton, cap.markers[: cap.phases["gym"][1]], rate_hz=cap.rate, source="synthetic")
    save_model(model, tmp / "model.json")
    print_context("0 (SyntheticActor kiip_full_body seed 0: the model's capture; the synthetic_actor node's default "
                  "seed 0, 0.5 mm noise)", f"the synthetic_actor node at 240 Hz, looping; the model calibrated on frames "
                  f"0-{cap.phases['gym'][1] - 1} (base and gym) of the same actor at 240 Hz",
                  f"the frames retargeted in {seconds:g} s after the graph is ready, the first 10 % dropped",
                  section="graph" + (", keep_up" if keep_up else "") + (", composed" if composed else ""))
    graph = tmp / "g.yaml"
    process = "\n    process: pipeline" if composed else ""
    graph.write_text(f"""
nodes:
  - name: reader
    type: synthetic_actor
    params: {{layout: kiip_full_body, rate_hz: 240.0, noise_mm: 0.5, loop: true}}
  - name: calibration
    type: calibration
    params: {{model_file: "{tmp / 'model.json'}"}}
  - name: solver
    type: frame_solver{process}
  - name: retargeter
    type: retargeter{process}
    params: {{source: actor, character: standard_20, foot_planting: true, keep_up: {str(keep_up).lower()}}}
  - name: rec
    type: bag_recorder
    params: {{path: "{tmp / 'lat.mcap'}", topics: [actor_pose, character_pose, diagnostics]}}
""")
    env = dict(os.environ, MOCAPGRAPH_MASTER=f"ipc://{tmp / ('m-' + uuid.uuid4().hex[:6])}", PYTHONUNBUFFERED="1")
    log = open(tmp / "launch.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph)], cwd=tmp, env=env,
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        t_end = time.monotonic() + 180
        while time.monotonic() < t_end and "nodes ready in" not in (tmp / "launch.log").read_text():
            time.sleep(0.2)
        time.sleep(seconds)
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    log.close()
    if not (tmp / "lat.mcap").exists():
        print("graph: no recording; launch output:\n" + (tmp / "launch.log").read_text()[-3000:])
        return
    with BagReader(tmp / "lat.mcap") as r:
        actor = {m.frame_number: e.publish_ns for e, m in r.decoded("actor_pose")}
        char = [(m.frame_number, e.publish_ns) for e, m in r.decoded("character_pose")]
        diag = [m for _, m in r.decoded("diagnostics")]
    lat = np.array([(p - actor[f]) * 1e-6 for f, p in char if f in actor])
    lat = lat[len(lat) // 10:]   # skip the start-up transient
    how = "solver and retargeter composed in one process (process: pipeline)" if composed else "a process per node"
    print(f"graph at 240 Hz (synthetic actor -> calibration -> solver -> retargeter{', keep_up' if keep_up else ''}; "
          f"{how}), {len(lat)} of {len(actor)} frames retargeted:")
    print(f"  latency the retargeter adds (CharacterPose minus ActorPose publish stamp): p50 {np.percentile(lat, 50):.3f} ms, "
          f"p90 {np.percentile(lat, 90):.3f} ms, p99 {np.percentile(lat, 99):.3f} ms, max {lat.max():.3f} ms "
          f"(target p99 <= 0.3 ms)")
    # breakdown: the hop solver -> retargeter (publish to receive, the retargeter's own edge figures:
    # per-second medians and maxima over its 512-frame window) and what remains (the node's work and
    # its waits for a core), with the node's CPU from its diagnostics
    hop, hop_max, cpu = [], [], []
    for m in diag:
        if m.node != "retargeter":
            continue
        cpu.append((m.uptime_s, m.cpu_s))
        for k, (tp, sd) in enumerate(zip(m.edge_topics, m.edge_senders)):
            if tp == "actor_pose" and sd == "solver" and np.isfinite(m.edge_latency_ms[k]):
                hop.append(m.edge_latency_ms[k])
                hop_max.append(m.edge_latency_max_ms[k])
    hop, hop_max = np.array(hop[len(hop) // 5:]), np.array(hop_max[len(hop_max) // 5:])
    if len(hop) and not keep_up:   # (with keep_up the edge figures include the frames skipped)
        h50 = float(np.median(hop))
        print(f"  of which the hop solver -> retargeter (publish to receive, the node's edge stats): p50 {h50:.3f} ms, "
              f"max per second {np.median(hop_max):.3f} ms median, {hop_max.max():.3f} ms worst; the rest (decode, "
              f"retarget, encode, waiting for a core): p50 {np.percentile(lat, 50) - h50:.3f} ms")
    if len(cpu) >= 2:
        (u0, c0), (u1, c1) = cpu[len(cpu) // 2], cpu[-1]   # the second half: start-up (imports, kernels) long over
        n = max(1.0, (u1 - u0) * 240.0)
        whose = "the composed process's CPU (solver and retargeter)" if composed else "retargeter process CPU"
        print(f"  {whose} {1e6 * (c1 - c0) / n:.0f} us per 240 Hz frame (everything: bus, diagnostics, "
              f"retargeting); load average now {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


def bench_shipped(seconds: float, viewer: bool = True) -> None:
    """The shipped graph as a lab runs it, viewer included: retarget_optical.yaml at 240 Hz onto
    standard_20 with the solver and retargeter composed (pipeline_process:=live); this process
    subscribes to actor_pose and character_pose and pairs them by capture stamp (the retargeter
    publishes its frame with the ActorPose's). Calibration runs live first (the actor's base pose
    and gym), so the measurement starts when the first character frame comes."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from _launched import launched_latencies_ms
    graph = (f"include:\n  - file: {REPO / 'graph_configs/retarget_optical.yaml'}\n"
             "    args: {character: standard_20, rate: 240.0, pipeline_process: live, viewer_port: 0, "
             f"viewer: {str(viewer).lower()}}}\n")
    print_context("0 (lab_synthetic.yaml's default seed; 0.5 mm noise)",
                  "graph_configs/retarget_optical.yaml: the synthetic_actor node (kiip_full_body) at 240 Hz, calibrated "
                  "live, onto standard_20",
                  f"frames paired on both topics from 1 s after the first pair, for {seconds:g} s", section="shipped graph")
    v = np.asarray(launched_latencies_ms(graph, "actor_pose", "character_pose", seconds, warm_s=1.0, start_timeout_s=120.0))
    if not len(v):
        print("shipped graph: no character frames (calibration did not finish in time?)")
        return
    print(f"shipped graph retarget_optical.yaml (240 Hz, standard_20, pipeline_process:=live, viewer "
          f"{'on' if viewer else 'off'}), "
          f"{len(v)} frames over {seconds:g} s:")
    print(f"  latency the retargeter adds: p50 {np.percentile(v, 50):.3f} ms, p90 {np.percentile(v, 90):.3f} ms, "
          f"p99 {np.percentile(v, 99):.3f} ms, "
          f"max {v.max():.3f} ms (target p99 <= 0.3 ms; load average {' '.join(f'{x:.1f}' for x in os.getloadavg())})")


def bench_hop(count: int) -> None:
    """The raw reference for the graph's hop: one frame between two Python processes at 240 Hz,
    raw pyzmq and mocapgraph nodes (benchmarks/bus.py's measurement), same run."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    import bus
    tmp = Path(tempfile.mkdtemp(prefix="retarget_hop_"))
    print_context(bus.SEED, bus.DATA, f"{count} frames at 240 Hz each way (raw pyzmq, mocapgraph), the first 20 "
                  "dropped (warm-up)", section="hop reference")
    raw = bus.raw_latency(tmp, 240.0, count) / 1e6
    mg = bus.mocapgraph_latency(tmp, 240.0, count) / 1e6
    print(f"raw hop reference at 240 Hz, 64-marker frame between two Python processes ({len(raw)} / {len(mg)} frames):")
    print(f"  raw pyzmq: p50 {np.percentile(raw, 50):.3f} ms, p99 {np.percentile(raw, 99):.3f} ms; mocapgraph nodes: "
          f"p50 {np.percentile(mg, 50):.3f} ms, p99 {np.percentile(mg, 99):.3f} ms; load average "
          f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--live-frames", type=int, default=2000)
    ap.add_argument("--graph-s", type=float, default=10.0)
    ap.add_argument("--no-graph", action="store_true")
    ap.add_argument("--graph-only", action="store_true", help="only the hop reference and the graphs")
    a = ap.parse_args()
    print(f"load average before: {' '.join(f'{x:.1f}' for x in os.getloadavg())} ({os.cpu_count()} cores)")
    if not a.graph_only:
        bench_live(a.live_frames)
        bench_node_path(a.live_frames)
        bench_batch()
    if not a.no_graph:
        bench_hop(1200)
        bench_graph(a.graph_s)
        bench_graph(a.graph_s, keep_up=True)
        bench_graph(a.graph_s, composed=True)
        bench_shipped(a.graph_s)
    print(f"load average after: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


if __name__ == "__main__":
    main()
