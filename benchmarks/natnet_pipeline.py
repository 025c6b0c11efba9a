"""The optical pipeline from the NatNet simulator beside the same performer through lab_udp: frames, gaps, joint errors.

Run: .venv/bin/python benchmarks/natnet_pipeline.py [--seconds 40] [--rate 240]
Launches lab_natnet.yaml fed by `mocapgraph device simulate natnet` and lab_udp.yaml fed by
`mocapgraph device simulate udp` (each its own process; the same synthetic performer, Plug-in Gait,
seed 0, the same 1 mm noise draws), each for ``--seconds`` at ``--rate``, with auto calibration and the frame solver.
Prints per lab: marker frames the reader counted of those sent and its gaps and rejects (its
reader_status), poses solved, poses missing between the first solved frame and the last frame sent,
and the solved joint error against the synthetic actor's ground truth (mean, p99, max, mm).
"""
from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mocapgraph.kinematics.synthetic.actor import SyntheticActor

from _context import print_context
from _launched import launched_graph

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def read(path: Path, topic: str) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        if r.get("topic") == topic:
            out.append(r["msg"])
    return out


def run_lab(lab: str, port: int, sim: list[str], tmp: Path, n: int, rate: float, noise_mm: float) -> tuple[dict, dict[int, list]]:
    log, slog = tmp / f"{lab}.jsonl", tmp / f"{lab}-session.jsonl"
    port_arg = "command_port" if lab == "lab_natnet" else "port"
    graph = f"""\
include:
  - file: {ROOT / 'graph_configs' / (lab + '.yaml')}
    args: {{viewer: false, layout: plug_in_gait, {port_arg}: {port}, session_log: {slog}}}
nodes:
  - name: poses
    type: topic_logger
    params: {{path: {log}, topics: [actor_pose]}}
"""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    work = tmp / lab
    work.mkdir(exist_ok=True)
    with launched_graph(graph, "actor_pose", work, timeout_s=120):
        time.sleep(2.0)
        subprocess.run([sys.executable, "-m", "mocapgraph", "device", "simulate", *sim, "--rate", str(rate),
                        "--count", str(n), "--layout", "plug_in_gait", "--noise-mm", str(noise_mm)], env=env, check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=n / rate + 120)
        t_end = time.monotonic() + 30
        while time.monotonic() < t_end and (n - 1) not in {p["frame_number"] for p in read(log, "actor_pose")[-50:]}:
            time.sleep(0.5)
    status = [s for s in read(slog, "reader_status")]
    poses = {p["frame_number"]: p["joint_positions"] for p in read(log, "actor_pose")}
    return json.loads(status[-1]["data_json"]) if status else {}, poses


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--rate", type=float, default=240.0)
    ap.add_argument("--noise-mm", type=float, default=1.0, help="marker noise of both simulators (the same draws)")
    args = ap.parse_args()
    n = int(args.seconds * args.rate)
    print_context(0, f"synthetic actor plug_in_gait seed 0, noise {args.noise_mm:g} mm, as NatNet 4.1 and as "
                  "wire-protocol UDP",
                  f"frames 0..{n - 1} at {args.rate:g} Hz; errors over every frame solved")
    actor = SyntheticActor("plug_in_gait", rate=args.rate, seed=0)
    session = actor.capture(0, actor.n_frames).joint_centres   # the simulators loop the session
    truth = session[np.arange(n) % len(session)]
    print(f"{'lab':<12}{'frames':>14}{'gaps':>6}{'rejected':>9}{'poses':>7}{'missing':>8}"
          f"{'err mean':>10}{'p99':>8}{'max':>8}  (mm)")
    with tempfile.TemporaryDirectory() as tmp:
        for lab in ("lab_natnet", "lab_udp"):
            port = free_port()
            sim = (["natnet", "--port", str(port), "--wait", "60", "--natnet", "4.1"] if lab == "lab_natnet"
                   else ["udp", "--to", f"127.0.0.1:{port}"])
            st, poses = run_lab(lab, port, sim, Path(tmp), n, args.rate, args.noise_mm)
            frames = sorted(f for f in poses if 0 <= f < n)
            if not frames:
                print(f"{lab:<12} no poses solved; reader status {st}")
                continue
            got = np.array([[[np.nan if v is None else v for v in j] for j in poses[f]] for f in frames], float)
            err = np.linalg.norm(got - truth[frames], axis=-1) * 1000
            missing = (frames[-1] - frames[0] + 1) - len(frames)
            print(f"{lab:<12}{st.get('frames', 0):>7} of {n:<5}{st.get('gaps', st.get('device_gaps', 0)):>6}"
                  f"{st.get('rejected_total', st.get('rejected_frames', 0)):>9}{len(frames):>7}{missing:>8}"
                  f"{np.nanmean(err):>10.3f}{np.nanpercentile(err, 99):>8.3f}{np.nanmax(err):>8.3f}")


if __name__ == "__main__":
    main()
