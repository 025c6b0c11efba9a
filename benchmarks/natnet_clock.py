"""NatNet capture stamps against the simulator's true capture times under injected delay and clock drift, over time.

Run: .venv/bin/python benchmarks/natnet_clock.py [--seconds S] [--rate HZ] [--drift-ppm P] [--delay-ms D]
The NatNet simulator (this process, a thread) serves the synthetic actor with every frame held back
a random 0..D ms (datagrams may overtake each other) and Motive's clock running P ppm fast (both
signs are run); the natnet_reader node runs in its own process, as the launcher starts it. For
each published frame, its capture stamp minus the frame's true mid-exposure time (the
simulator's schedule, ``Faults.captured``) is the error. Printed per span of the run: the error's
min / median / max, ms, and the share of frames within 1 ms; and after 2 s overall. A stamp can be
no better than the fastest path from simulator to reader (one-way delay below it is invisible), so
the error's floor is that path: a few tenths of a ms on an idle machine, more on a loaded one.
The simulator's own lateness is printed too: on a machine so busy that this process stalls for
over 0.5 s, frames leave that late for over a second, which ClockSync takes for the device's clock
having stood still (a reset, docs/clock.md): stamps are off by the stall until it recovers.
"""
from __future__ import annotations

import argparse
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from mocapgraph.messages import decode
from mocapgraph.testing.natnet_server import ActorStream, Faults, simulate

from _context import print_context
from _launched import reader_process, stop_reader

START = 1000


def run(seconds: float, rate: float, drift_ppm: float, delay_ms: float) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    stream = ActorStream("plug_in_gait", rate_hz=rate, n_bodies=0, n_unlabelled=0)
    faults = Faults(delay_ms=(0.0, delay_ms), drift_ppm=drift_ppm, seed=1)
    n = int(seconds * rate)
    truth: dict[int, int] = {}
    stamps: dict[int, int] = {}
    with tempfile.TemporaryDirectory() as d:
        proc, sub = reader_process(Path(d), "mocapgraph.nodes.natnet_reader:NatNetReader",
                                   {"server": "127.0.0.1", "command_port": port, "retry_s": 0.2})
        sim = threading.Thread(target=simulate, kwargs=dict(stream=stream, version=(4, 1), command_port=port, count=n,
                                                            start_frame=START, faults=faults, wait_s=20.0), daemon=True)
        sim.start()
        try:
            t_end = time.monotonic() + seconds + 30
            while time.monotonic() < t_end and (sim.is_alive() or sub.poll(500)):
                while faults.captured:                      # drained as it goes (the log is bounded)
                    k, ns = faults.captured.popleft()
                    truth[k] = ns
                if sub.poll(100):
                    env, msg = decode(sub.recv_multipart())
                    stamps[msg.frame_number] = env.capture_ns
                elif proc.poll() is not None:
                    raise SystemExit(f"reader exited: {proc.stderr.read()[-2000:]}")
        finally:
            stop_reader(proc, sub)
    truth.update(faults.captured)
    ks = np.array(sorted(k for k in stamps if k in truth))
    err = np.array([(stamps[k] - truth[k]) / 1e6 for k in ks])
    t = (ks - START) / rate
    print(f"drift {drift_ppm:+.0f} ppm, delay 0-{delay_ms:g} ms, {rate:g} Hz, {seconds:g} s: {len(ks)} of {n} frames "
          f"published (frames overtaken on the way are dropped by the reader); the simulator itself sent "
          f"{faults.late_over_500ms} frames over 0.5 s late (worst {faults.late_ms_max:.0f} ms: this process stalled)")
    edges = np.linspace(0, seconds, 7)
    for a, b in zip(edges[:-1], edges[1:]):
        e = err[(t >= a) & (t < b)]
        if len(e):
            print(f"  {a:6.1f}-{b:6.1f} s  error min {e.min():7.3f}  median {np.median(e):7.3f}  max {e.max():8.3f} ms"
                  f"  within 1 ms {100 * np.mean(np.abs(e) < 1.0):5.1f} %")
    late = err[t >= 2.0]
    if len(late):
        print(f"  after 2 s: |error| max {np.abs(late).max():.3f} ms, p99 {np.percentile(np.abs(late), 99):.3f} ms, "
              f"within 1 ms {100 * np.mean(np.abs(late) < 1.0):.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="per drift sign (600 = the issue's 10 minutes)")
    ap.add_argument("--rate", type=float, default=240.0)
    ap.add_argument("--drift-ppm", type=float, default=100.0)
    ap.add_argument("--delay-ms", type=float, default=20.0)
    args = ap.parse_args()
    print_context(1, "synthetic actor plug_in_gait (39 markers), NatNet 4.1 unicast on loopback",
                  f"{args.seconds:g} s at {args.rate:g} Hz per drift sign", section="clock")
    for drift in (args.drift_ppm, -args.drift_ppm):
        run(args.seconds, args.rate, drift, args.delay_ms)


if __name__ == "__main__":
    main()
