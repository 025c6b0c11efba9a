"""Device clock estimate (messages.clock_sync) over ten simulated minutes: capture-stamp error over time.

Run: .venv/bin/python benchmarks/clock.py [--minutes M] [--live S]
Pure arithmetic, no sockets (about 2 s): a device pacing frames by its own clock, 100 ppm fast or
slow against ours, every frame 0-20 ms late on the link (uniform, independent). Prints, per span of
simulated time, the largest |capture stamp - true capture time| of ClockSync beside the first-frame
offset readers used before; then the same with the delays of a FIFO queue (a frame never overtakes
the one before: fast frames are rarer, so the floor is found later); then the per-frame cost.
``--live S`` adds S seconds of the UDP device simulator into a socket in this process (real
scheduling; the machine's own fastest path is part of the error there).
"""
from __future__ import annotations

import argparse
import socket
import threading
import time

import numpy as np

from mocapgraph.messages.clock_sync import ClockSync

from _context import print_context

T0 = 1_800_000_000_000_000_000
SPANS = [(0, 1), (1, 2), (2, 5), (5, 10), (10, 30), (30, 60), (60, 120), (120, 300), (300, 600)]


def synthetic(rate: float, seconds: float, drift_ppm: float, seed: int, fifo: bool):
    k = np.arange(int(rate * seconds))
    dev = 5_000_000_000 + np.round(k * 1e9 / rate).astype(np.int64)
    true = T0 + np.round(k * 1e9 / rate / (1 + drift_ppm * 1e-6)).astype(np.int64)
    leave = true + np.round(np.random.default_rng(seed).uniform(0, 20e6, k.size)).astype(np.int64)
    if fifo:
        leave = np.maximum.accumulate(leave)
    order = np.argsort(leave, kind="stable")
    return k / rate, dev[order], true[order], leave[order], (k / rate)[order]


def spans_line(t: np.ndarray, err_ms: np.ndarray, minutes: float) -> str:
    cells = []
    for a, b in SPANS:
        if a >= minutes * 60:
            break
        m = (t >= a) & (t < b)
        cells.append(f"{a}-{b}s {np.abs(err_ms[m]).max():7.3f}")
    return " | ".join(cells)


def run_case(rate: float, drift: float, minutes: float, seed: int, fifo: bool) -> float:
    _, dev, true, arrival, t = synthetic(rate, minutes * 60, drift, seed, fifo)
    sync = ClockSync()
    pairs = list(zip(dev.tolist(), arrival.tolist()))          # Python ints, as a reader has them
    update = sync.update
    t0 = time.perf_counter()
    cap = [update(d, a) for d, a in pairs]
    per_frame_us = (time.perf_counter() - t0) / dev.size * 1e6
    cap = np.array(cap)
    err = (cap - true) / 1e6
    first = (dev + (arrival[0] - dev[0]) - true) / 1e6
    st = sync.stats()
    kind = "FIFO " if fifo else "indep"
    print(f"{rate:5.0f} Hz {drift:+5.0f} ppm {kind} ClockSync   max|err| ms  {spans_line(t, err, minutes)}")
    print(f"{'':24} first frame max|err| ms  {spans_line(t, first, minutes)}")
    print(f"{'':24} after 2 s: max {np.abs(err[t >= 2]).max():.3f} ms, median {np.median(err[t >= 2]):.3f} ms; "
          f"reported drift {st.drift_ppm:+.1f} ppm, jitter {st.jitter_ms:.2f} ms, delay {st.delay_ms:.2f} ms, "
          f"{st.points} points kept, {st.resets} resets")
    return per_frame_us


def live(seconds: float) -> None:
    from mocapgraph.formats.wire_protocol import make_decoder
    from mocapgraph.testing.device_simulator import SimulatedDevice, run_udp

    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(2.0)
    sim = SimulatedDevice("plug_in_gait", "example_udp_bridge", rate_hz=240.0, seed=3, drift_ppm=100.0, delay_ms=20.0)
    n = int(240 * seconds)
    tx = threading.Thread(target=run_udp, args=(sim, "127.0.0.1", rx.getsockname()[1]), kwargs={"count": n})
    tx.start()
    dec, sync, got = make_decoder("binary"), ClockSync(), []
    while len(got) < n:
        try:
            data = rx.recv(65535)
        except socket.timeout:
            break
        now = time.time_ns()
        for wf in dec.feed(data) + dec.flush():
            got.append((wf.frame, now, sync.update(wf.device_time_ns, now)))
    tx.join()
    rx.close()
    k = np.array([g[0] for g in got])
    true = sim.capture_ns(k)
    err = (np.array([g[2] for g in got]) - true) / 1e6
    path = (np.array([g[1] for g in got]) - true) / 1e6
    t = k / 240.0
    late = t >= 2
    st = sync.stats()
    print(f"live UDP {seconds:.0f} s at 240 Hz, +100 ppm, 0-20 ms: "
          f"after 2 s max|err| {np.abs(err[late]).max():.3f} ms, "
          f"median {np.median(err[late]):.3f} ms; fastest path (arrival - true) {path.min():.3f} ms; "
          f"drift {st.drift_ppm:+.1f} ppm, jitter {st.jitter_ms:.2f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--live", type=float, default=0.0, help="seconds of the UDP simulator into a socket (0: none)")
    args = ap.parse_args()
    print_context(seed="1, 2, 3", data="synthetic (device time, arrival) pairs", split=None)
    cost = [run_case(240.0, 100.0, args.minutes, 1, False), run_case(120.0, -100.0, args.minutes, 2, False),
            run_case(240.0, 100.0, args.minutes, 3, True)]
    print(f"ClockSync.update: {np.mean(cost):.2f} us per frame (pure Python)")
    if args.live:
        live(args.live)


if __name__ == "__main__":
    main()
