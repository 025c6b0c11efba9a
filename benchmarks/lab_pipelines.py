"""The lab graphs (NatNet, QTM, UDP) from their simulators with one performer: frames, gaps, joint errors, added latency.

Run: .venv/bin/python benchmarks/lab_pipelines.py [--seconds 60] [--rate 240] [--labs natnet,qtm,udp]
Launches lab_natnet.yaml fed by `mocapgraph device simulate natnet` (NatNet 4.1), lab_qtm.yaml fed
by `mocapgraph device simulate qtm` (QTM RT over TCP) and lab_udp.yaml fed by `mocapgraph device
simulate udp` (wire protocol; lab_udp's device:='' and the simulator's --device '', since the
example bridge's device file names Plug-in Gait channels only), one after the other, each in its own processes: the
same synthetic performer (``--layout``, kiip_full_body's 62 markers by default, seed 0, the same
``--noise-mm`` draws) at ``--rate``, with auto calibration and the frame solver. Each simulator sends
``--lead-s`` of frames first (the calibration's base pose and gym, and its solve), then the
``--seconds`` measured.

Prints per lab, from this process's own subscription to markers, actor_pose and reader_status:
- frames: marker frames the reader counted (its reader_status) of those the simulator says it sent
  (its "sent N frames" line; the QTM simulator's count starts when the reader asks for frames);
- gaps: frame numbers the reader reports skipped, and those this benchmark sees missing among the
  published MarkerFrames (``unreported`` = seen minus reported; 0 means every missing frame number
  is in the reader's counters);
- the capture time of the first pose (when the auto calibration was done: it must fall inside the
  lead), poses solved of the measured window's frames, the solved joint error against the synthetic
  actor's ground truth (mean, p99, max, mm; joints over the window);
- the latency reader -> solver the pipeline adds: the ActorPose publish stamp minus the MarkerFrame
  publish stamp of the same capture (p50, p99, ms), per lab in the same run, so NatNet's and QTM's
  sit beside udp_reader's (the tails follow the machine's load: each row ends with the 1-min load
  average as its lab ended).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapgraph.bus.manifest import subscribe
from mocapgraph.kinematics.synthetic.actor import SyntheticActor
from mocapgraph.messages import decode

from _context import print_context
from _launched import launched_graph

ROOT = Path(__file__).resolve().parents[1]
LABS = ("natnet", "qtm", "udp")


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def lab_setup(lab: str) -> tuple[dict, list[str]]:
    """The lab graph's launch args (its port) and its simulator's transport args."""
    if lab == "natnet":
        port = free_port()
        return {"command_port": port}, ["natnet", "--port", str(port), "--wait", "60", "--natnet", "4.1"]
    if lab == "qtm":
        port = free_port(socket.SOCK_STREAM)
        return {"port": port}, ["qtm", "--port", str(port), "--bodies", "5"]
    port = free_port()
    # no device file: the example bridge's channels are Plug-in Gait's; '' sends the layout's markers
    return {"port": port, "device": "''"}, ["udp", "--to", f"127.0.0.1:{port}", "--device", ""]


@dataclass
class Run:
    """What this process saw of one lab's run."""
    markers: dict[int, tuple[int, int]] = field(default_factory=dict)   # frame -> (capture_ns, publish_ns)
    poses: dict[int, tuple[int, int, np.ndarray]] = field(default_factory=dict)   # frame -> (cap, pub, joints)
    status: dict = field(default_factory=dict)
    status_at: float = 0.0
    marker_at: float = 0.0
    sim_said: str = ""   # the simulator's last line on stderr


def receive(sock, run: Run) -> None:
    env, msg = decode(sock.recv_multipart())
    if env.topic == "markers":
        run.markers[msg.frame_number] = (env.capture_ns, env.publish_ns)
        run.marker_at = time.monotonic()
    elif env.topic == "actor_pose":
        run.poses[msg.frame_number] = (env.capture_ns, env.publish_ns, np.array(msg.joint_positions, float))
    elif env.topic == "reader_status":
        run.status, run.status_at = json.loads(msg.data_json or "{}"), time.monotonic()


def run_lab(lab: str, tmp: Path, count: int, args: argparse.Namespace) -> Run:
    graph_args, sim = lab_setup(lab)
    slog = tmp / f"{lab}-session.jsonl"
    extra = ", ".join(f"{k}: {v}" for k, v in graph_args.items())
    graph = f"""\
include:
  - file: {ROOT / 'graph_configs' / f'lab_{lab}.yaml'}
    args: {{viewer: false, layout: {args.layout}, {extra}, session_log: {slog}}}
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    work = tmp / lab
    work.mkdir(exist_ok=True)
    run = Run()
    with launched_graph(graph, "actor_pose", work, timeout_s=120) as manifest:
        sock = subscribe(manifest, ["markers", "actor_pose", "reader_status"])
        time.sleep(2.0)
        err = (work / "sim.err").open("w")
        proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "simulate", *sim,
                                 "--rate", str(args.rate), "--count", str(count), "--layout", args.layout,
                                 "--seed", "0", "--noise-mm", str(args.noise_mm)], env=env,
                                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)
        t_sent = time.monotonic() + count / args.rate + 15.0   # the last frame is out by then
        t_end = t_sent + 30.0
        try:
            while time.monotonic() < t_end:
                if sock.poll(100):
                    receive(sock, run)
                    continue
                done = proc.poll() is not None or (count - 1) in run.markers or time.monotonic() > t_sent
                last = max(run.markers, default=-1)
                # a reader status after the last frame, and the pose of the last frame (or a quiet spell)
                if done and last >= 0 and run.status_at > run.marker_at and (
                        last in run.poses or time.monotonic() - run.marker_at > 3.0):
                    break
        finally:
            sock.close(0)
            if proc.poll() is None:   # (the QTM simulator serves on: SIGINT has it print what it sent)
                proc.send_signal(signal.SIGINT)
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:   # (SIGINT ignored: started from a non-interactive shell's &)
                proc.kill()
                proc.wait()
            err.close()
    said = (work / "sim.err").read_text(errors="replace").strip().splitlines()
    run.sim_said = said[-1] if said else ""
    return run


def report(lab: str, run: Run, count: int, lead: int, rate: float, truth: np.ndarray) -> None:
    st = run.status
    got = sorted(run.markers)
    if not got:
        print(f"{lab:<8} no marker frames published; reader status {st}; simulator: {run.sim_said or '(silent)'}")
        return
    first = got[0]
    said = re.search(r"sent (\d+) frames", run.sim_said)   # the simulator's own count, else all from the first
    sent = int(said[1]) if said else count - first
    seen_missing = (count - first) - len([f for f in got if f < count])
    reported = st.get("gaps", st.get("device_gaps", 0))
    window = [f for f in range(max(lead, first), count)]
    solved = [f for f in window if f in run.poses]
    first_pose = f"{min(run.poses) / rate:.1f}" if run.poses else "-"
    line = (f"{lab:<8}{st.get('frames', 0):>7} of {sent:<6}{reported:>7}{seen_missing:>6}"
            f"{max(0, seen_missing - reported):>11}{first_pose:>7}{len(solved):>7} of {len(window):<6}")
    if not solved:
        print(line + "  no poses in the window")
        return
    joints = np.stack([run.poses[f][2] for f in solved])
    err = np.linalg.norm(joints - truth[np.asarray(solved) % len(truth)], axis=-1) * 1000
    lat = np.array([(run.poses[f][1] - run.markers[f][1]) * 1e-6 for f in solved
                    if f in run.markers and run.poses[f][0] == run.markers[f][0]])
    lat_txt = f"{np.percentile(lat, 50):>8.2f}{np.percentile(lat, 99):>8.2f}" if len(lat) else f"{'-':>8}{'-':>8}"
    lat_txt += f"{os.getloadavg()[0]:>6.2f}"   # the tails follow the machine's load: this lab's, as it ended
    print(line + f"{np.nanmean(err):>9.3f}{np.nanpercentile(err, 99):>8.3f}{np.nanmax(err):>8.3f}" + lat_txt,
          flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="measured stream per lab, s (after the lead)")
    ap.add_argument("--lead-s", type=float, default=30.0, help="frames sent before the measured window, s "
                    "(auto calibration: base pose, 16 s of gym, its solve)")
    ap.add_argument("--rate", type=float, default=240.0)
    ap.add_argument("--layout", default="kiip_full_body", help="marker layout the performer wears")
    ap.add_argument("--noise-mm", type=float, default=1.0, help="marker noise of every simulator (the same draws)")
    ap.add_argument("--labs", default=",".join(LABS), help="comma-separated subset of natnet,qtm,udp")
    args = ap.parse_args()
    labs = [s.strip() for s in args.labs.split(",") if s.strip()]
    if not labs or any(lab not in LABS for lab in labs):
        ap.error(f"--labs: pick from {','.join(LABS)}")
    lead, n = int(args.lead_s * args.rate), int(args.seconds * args.rate)
    count = lead + n
    actor = SyntheticActor(args.layout, rate=args.rate, seed=0)
    print_context(0, f"synthetic actor {args.layout} ({len(actor.skeleton.marker_labels)} markers) seed 0, "
                  f"noise {args.noise_mm:g} mm, as NatNet 4.1, QTM RT (TCP) and wire-protocol UDP",
                  f"frames 0..{count - 1} at {args.rate:g} Hz; errors and latency over frames {lead}..{count - 1} "
                  f"({args.seconds:g} s after a {args.lead_s:g} s calibration lead)")
    truth = actor.capture(0, actor.n_frames).joint_centres   # the simulators loop the session
    print("frames: counted by the reader of those the simulator sent; gaps: reported by the reader, seen missing here, "
          "seen but unreported;\npose@s: capture time of the first pose (calibration done); poses solved in "
          "the window; joint error vs ground truth (mm);\nlat: added latency reader -> solver (ActorPose minus "
          "MarkerFrame publish stamp of the same capture, ms); load: 1-min load average as the lab ended")
    print(f"{'lab':<8}{'frames':>15}{'gaps':>7}{'seen':>6}{'unreported':>11}{'pose@s':>7}{'poses':>15}"
          f"{'err mean':>9}{'p99':>8}{'max':>8}{'lat p50':>8}{'p99':>8}{'load':>6}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        for lab in labs:
            report(lab, run_lab(lab, Path(tmp), count, args), count, lead, args.rate, truth)


if __name__ == "__main__":
    main()
