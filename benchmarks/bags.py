"""Bag benchmark: record throughput, replay timing, recovery speed.

Prints:
- record throughput in messages/s for 64-marker MarkerFrames (changing positions, so compression
  sees real float64 data), for lz4 and no compression:
    * "recorder": the recording path alone (envelope decode, sequence check, framing, MCAP write,
      compression, a chunk flush every 0.25 s) fed pre-encoded frames;
    * "live": a publisher process sending as fast as it can over ipc into a recorder subscribed
      without a high-water mark (the `bag record` loop), with the messages lost (target 0);
  target: at least 50k messages/s with lz4;
- file size per message and the compression ratio;
- replay timing at 240 Hz through `mocapgraph bag play`: each message's send time (its publish
  stamp) and arrival time at a subscriber against its recorded offset scaled by the rate, p50/p99/
  max in ms (lateness against the schedule, whose origin is taken from the least late message),
  with default scheduling and with --realtime (SCHED_FIFO; matters when the machine is busy);
- recovery speed of a truncated bag (MB/s and messages/s), and a full scan (`bag info`).

Usage: python benchmarks/bags.py [--messages 200000] [--replay-s 20] [--tmp DIR]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import zmq

from mocapgraph.bag.reader import BagReader
from mocapgraph.bag.recorder import Recorder
from mocapgraph.bag.recover import recover
from mocapgraph.bag.writer import BagWriter
from mocapgraph.messages import MarkerFrame, MarkerLayout, decode_envelope, encode
from mocapgraph.messages.codec import topic_frame
from mocapgraph.testing.marker_pattern import pattern_positions

from _context import print_context

N_MARKERS = 64
RATE = 240.0


def frames_for(i: int, rng: np.random.Generator, t_ns: int) -> list[bytes]:
    # a device's float32 millimetres converted to float64 metres, as C3D files and most cameras deliver
    pos = pattern_positions(i, N_MARKERS, RATE) + rng.normal(scale=2e-4, size=(N_MARKERS, 3))
    pos = (pos * 1000).astype(np.float32).astype(np.float64) / 1000
    msg = MarkerFrame(frame_number=i, rate_hz=RATE, positions=pos, valid=np.ones(N_MARKERS, bool),
                      residual=rng.random(N_MARKERS).astype(np.float32) * 1e-3)
    return [bytes(f) for f in encode("markers", msg, i + 1, t_ns, "bench", t_ns)]


def pool(n: int = 512) -> list[list[bytes]]:
    """Distinct pre-encoded frames (sequence numbers patched per message later)."""
    rng = np.random.default_rng(0)
    return [frames_for(i, rng, 0) for i in range(n)]


def with_seq(frames: list[bytes], seq: int, t_ns: int) -> list[bytes]:
    head = bytearray(frames[1])
    head[10:18] = seq.to_bytes(8, "little")
    head[18:26] = t_ns.to_bytes(8, "little", signed=True)
    head[26:34] = t_ns.to_bytes(8, "little", signed=True)
    return [frames[0], bytes(head), *frames[2:]]


def bench_recorder(tmp: Path, n: int, compression: str) -> tuple[float, float, int]:
    src = pool()
    msgs = [with_seq(src[i % len(src)], i + 1, 10**9 + i) for i in range(n)]
    path = tmp / f"rec_{compression}.mcap"
    rec = Recorder(BagWriter(path, compression=compression))
    t0 = time.perf_counter()
    for i, f in enumerate(msgs):
        rec.receive(f)
        if i % 256 == 0:
            rec.tick()
    rec.close()
    dt = time.perf_counter() - t0
    raw = sum(len(x) for f in msgs[:1000] for x in f) / 1000
    return n / dt, path.stat().st_size / n, int(raw)


def _publisher(ep: str, n: int, q) -> None:
    ctx = zmq.Context()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.SNDHWM, 0)
    pub.bind(ep)
    src = pool()
    q.put("ready")
    q.get()  # go
    t0 = time.perf_counter()
    for i in range(n):
        pub.send_multipart(with_seq(src[i % len(src)], i + 1, time.time_ns()))
    q.put(time.perf_counter() - t0)
    time.sleep(2.0)
    pub.close(linger=2000)


def bench_live(tmp: Path, n: int, compression: str) -> tuple[float, int, int]:
    ep = f"ipc://{tmp / ('live_' + compression)}"
    ctxmp = mp.get_context("spawn")
    q = ctxmp.Queue()
    proc = ctxmp.Process(target=_publisher, args=(ep, n, q))
    proc.start()
    q.get(timeout=30)
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, topic_frame("markers"))
    sub.connect(ep)
    time.sleep(0.5)
    rec = Recorder(BagWriter(tmp / f"live_{compression}.mcap", compression=compression))
    q.put("go")
    t_first = None
    idle_since = time.monotonic()
    while rec.received < n and time.monotonic() - idle_since < 3.0:
        if sub.poll(20):
            for _ in range(2000):
                try:
                    f = sub.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                if t_first is None:
                    t_first = time.perf_counter()
                rec.receive(f)
            idle_since = time.monotonic()
        rec.tick()
    t_last = time.perf_counter()
    rec.close()
    q.get(timeout=30)
    proc.join(10)
    sub.close(0)
    lost = n - rec.received
    return (rec.received - 1) / (t_last - t_first), lost, sum(rec.lost.values())


def make_replay_bag(path: Path, seconds: float) -> Path:
    rng = np.random.default_rng(1)
    t0 = 1_700_000_000 * 10**9
    period = int(1e9 / RATE)
    with BagWriter(path) as w:
        w.write("marker_layout", MarkerLayout(name="bench", labels=[f"M{k}" for k in range(N_MARKERS)],
                                              marker_limb=np.full(N_MARKERS, -1)), seq=1, capture_ns=t0)
        for i in range(int(seconds * RATE)):
            # a real capture's jitter: the recorded offsets are not a perfect grid
            t = t0 + i * period + int(rng.normal(scale=50_000))
            w.write_frames(frames_for(i, rng, t), t)
    return path


def bench_replay(bag: Path, rate: float, *extra: str) -> dict[str, np.ndarray]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        ep = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, topic_frame("markers"))
    sub.connect(ep)
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "bag", "play", str(bag), "--bind", ep,
                             "--no-manifest", "-q", "--rate", str(rate), *extra], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    got = []
    while True:
        if sub.poll(50):
            while True:
                try:
                    f = sub.recv_multipart(zmq.NOBLOCK)
                except zmq.Again:
                    break
                got.append((time.time_ns(), decode_envelope(f).publish_ns))
        elif proc.poll() is not None:
            break
    out = proc.stdout.read()
    sub.close(0)
    with BagReader(bag) as r:
        rec = np.array([m.publish_ns for m in r.messages(["markers"])], np.int64)
    arrive = np.array([a for a, _ in got], np.int64)
    sent = np.array([p for _, p in got], np.int64)
    assert len(sent) == len(rec), f"{len(sent)} of {len(rec)} messages arrived"

    def err(x: np.ndarray) -> np.ndarray:
        # lateness against the schedule, whose origin is the least late message (nothing is early)
        d = ((x - x[0]) - (rec - rec[0]) / rate) / 1e6
        return d - d.min()

    return {"send": err(sent), "arrival": err(arrive), "player": out.strip().splitlines()[-1]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--messages", type=int, default=200_000)
    ap.add_argument("--replay-s", type=float, default=20.0)
    ap.add_argument("--tmp", help="folder for the bags (default: a temporary one)")
    a = ap.parse_args()
    tmp = Path(a.tmp or tempfile.mkdtemp(prefix="bagbench-"))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        run(a, tmp)
    finally:
        if not a.tmp:
            shutil.rmtree(tmp, ignore_errors=True)


def run(a: argparse.Namespace, tmp: Path) -> None:
    print(f"64-marker MarkerFrame, {a.messages} messages, bags in {tmp}; load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    pooled = ("generated 64-marker MarkerFrames: the test pattern (240 Hz) + N(0, 0.2 mm) noise and random "
              "residuals, a pool of 512 distinct frames")
    print_context("0 (np.random.default_rng, the frame pool; the live publisher rebuilds the same pool)", pooled,
                  f"{a.messages} messages per run, the pool cycled", section="record")
    for comp in ("lz4", "none"):
        rate, per_msg, raw = bench_recorder(tmp, a.messages, comp)
        print(f"record ({comp:>4}) recorder path: {rate:9.0f} msg/s  file {per_msg:7.0f} B/msg "
              f"(message {raw} B, ratio {raw / per_msg:.2f})")
    for comp in ("lz4", "none"):
        rate, lost, gaps = bench_live(tmp, a.messages, comp)
        print(f"record ({comp:>4}) live over ipc:  {rate:9.0f} msg/s  lost {lost} (recorder counted {gaps})")
    bag = make_replay_bag(tmp / "replay.mcap", a.replay_s)
    print_context("1 (np.random.default_rng: frame noise, residuals and 50 us recording jitter)",
                  f"a generated replay bag: {int(a.replay_s * RATE)} 64-marker frames at 240 Hz (test pattern + noise)",
                  "every message of the bag, each rate", section="replay")
    for extra in ((), ("--realtime",)):
        for rate in (1.0, 4.0):
            r = bench_replay(bag, rate, *extra)
            for k in ("send", "arrival"):
                e = r[k]
                print(f"replay 240 Hz at {rate:g}x{' --realtime' if extra else ''}, {k:>7} time vs recorded offset: "
                      f"p50 {np.percentile(e, 50):.3f} ms  p99 {np.percentile(e, 99):.3f} ms  max {e.max():.3f} ms  "
                      f"({len(e)} msgs)")
            print(f"  player: {r['player']}")
    big = tmp / "rec_lz4.mcap"
    data = big.read_bytes()
    print_context("0 (the record section's frame pool)", f"the recorder's lz4 bag of {a.messages} messages",
                  "recover: its first 90 % of bytes; scan: the whole bag", section="recover, scan")
    cut = tmp / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.9)])
    t0 = time.perf_counter()
    rep = recover(cut, tmp / "cut.recovered.mcap")
    dt = time.perf_counter() - t0
    print(f"recover: {len(data) * 0.9 / 1e6 / dt:.0f} MB/s, {rep.saved / dt:.0f} msg/s "
          f"({rep.saved} saved, about {rep.lost_estimate} lost in the cut chunk, {dt:.2f} s)")
    t0 = time.perf_counter()
    with BagReader(big) as r:
        r.scan()
    dt = time.perf_counter() - t0
    print(f"scan (bag info): {a.messages / dt:.0f} msg/s, {len(data) / 1e6 / dt:.0f} MB/s")


if __name__ == "__main__":
    main()
