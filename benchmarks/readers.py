"""Reader speed and timing: replay throughput as fast as possible, and real-time jitter at 240 Hz.

Each reader runs as a real node process (``python -m mocapgraph.bus.runtime``, exactly as the
launcher starts it); this script subscribes from its own process and records the envelope's
publish stamps and its own receive stamps.

1. Replay as fast as possible (``rate_scale: 0``, looping): frames/s of the C3D reader
   (Movement_trial.c3d, 120 Hz, 39 Plug-in Gait markers in layout order) and of the BVH player
   (CMU 131_01.bvh, 120 Hz, 38 joints), received by a subscriber. Target: >= 20x the file's rate.
2. Real-time replay at 240 Hz: a 240 Hz C3D written from the synthetic actor (C3D replay), and
   the synthetic actor node itself at 240 Hz (live source), for ``--seconds``; the bus's own
   test-pattern node at 240 Hz first, as the baseline of what the machine allows right now. Jitter is the
   deviation of each frame interval from 1/240 s, from the publish stamps (the node's own
   timing) and from the receive stamps (what a subscriber sees). Target: p99 under 1 ms.

Usage: ``python benchmarks/readers.py [--seconds 10] [--frames 20000]``. Needs ../shared/data for
part 1 (skipped without it).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from mocapgraph.messages import decode_envelope

from _context import print_context
from _launched import reader_process, stop_reader

ROOT = Path(__file__).resolve().parents[1]
DATA = (ROOT / ".." / "shared" / "data").resolve()


def run_node(tmp: Path, cls: str, params: dict, topic: str, n_frames: int, timeout: float) -> np.ndarray:
    """Start one node process, receive ``n_frames`` on ``topic``; int64 [n, 2] (publish, receive) ns."""
    proc, sub = reader_process(tmp, cls, params, topic)
    out = np.zeros((n_frames, 2), np.int64)
    k = 0
    t_end = time.monotonic() + timeout
    try:
        while k < n_frames and time.monotonic() < t_end:
            if not sub.poll(200):
                if proc.poll() is not None:
                    raise SystemExit(f"node exited: {proc.stderr.read()[-2000:]}")
                continue
            frames = sub.recv_multipart()
            now = time.time_ns()
            out[k] = decode_envelope(frames).publish_ns, now
            k += 1
    finally:
        stop_reader(proc, sub)
    if k < n_frames:
        raise SystemExit(f"only {k} of {n_frames} frames within {timeout} s")
    return out


def throughput(tmp: Path, label: str, cls: str, params: dict, topic: str, file_rate: float, n: int) -> None:
    st = run_node(tmp, cls, params, topic, n, timeout=120)
    st = st[n // 10:]  # skip start-up
    pub_fps = (len(st) - 1) / ((st[-1, 0] - st[0, 0]) / 1e9)
    rx_fps = (len(st) - 1) / ((st[-1, 1] - st[0, 1]) / 1e9)
    print(f"  {label:<44} {rx_fps:9.0f} frames/s received ({rx_fps / file_rate:5.1f}x the file's "
          f"{file_rate:g} Hz; published {pub_fps:.0f}/s)  target >= 20x: {'OK' if rx_fps >= 20 * file_rate else 'MISSED'}")


def jitter(tmp: Path, label: str, cls: str, params: dict, rate: float, seconds: float) -> None:
    n = int(rate * seconds)
    st = run_node(tmp, cls, params, "markers", n, timeout=seconds * 3 + 30)
    st = st[int(rate * 0.5):]  # the first half second warms caches and the worker thread
    period_ms = 1000.0 / rate
    print(f"  {label} ({len(st)} frames, period {period_ms:.3f} ms):")
    for what, col in (("publish stamps", 0), ("receive stamps", 1)):
        dev = np.abs(np.diff(st[:, col]) / 1e6 - period_ms)
        p50, p99, p999 = np.percentile(dev, [50, 99, 99.9])
        late = (st[:, col] - st[0, col]) / 1e6 - np.arange(len(st)) * period_ms
        late -= np.median(late)
        stalls = int((np.diff(st[:, col]) / 1e6 > 2 * period_ms).sum())
        print(f"    {what:<15} interval jitter p50 {p50:6.3f}  p99 {p99:6.3f}  p99.9 {p999:6.3f}  max {dev.max():6.2f} ms"
              f" | drift from schedule p99 {np.percentile(np.abs(late), 99):6.3f} ms | {stalls} stalls > 2 periods"
              f"  target p99 < 1 ms: {'OK' if p99 < 1.0 else 'MISSED'}")
    lat = (st[:, 1] - st[:, 0]) / 1e6
    print(f"    publish->receive latency p50 {np.median(lat):.3f} ms, p99 {np.percentile(lat, 99):.3f} ms")


def write_240hz_c3d(path: Path, seconds: float) -> None:
    from mocapgraph.formats import MarkerTrial, write_c3d
    from mocapgraph.kinematics.synthetic.actor import SyntheticActor

    actor = SyntheticActor("plug_in_gait", rate=240.0, seed=1)
    cap = actor.capture(0, min(actor.n_frames, int(240 * (seconds + 2))))
    write_c3d(path, MarkerTrial(labels=list(actor.skeleton.marker_labels), positions=cap.markers, residuals=None,
                                rate_hz=240.0, source="synthetic actor"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each real-time run, s")
    ap.add_argument("--frames", type=int, default=20000, help="frames received per throughput run")
    args = ap.parse_args()
    print(f"readers benchmark: {os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory(prefix="mg-readers-") as td:
        tmp = Path(td)
        print("1. replay as fast as possible (rate_scale 0, loop), received by a subscriber process")
        if DATA.is_dir():
            print_context(None, f"real captures {DATA / 'c3d/pycgm/Movement_trial.c3d'} and {DATA / 'bvh/cmu/131_01.bvh'}",
                          f"{args.frames} frames received per file (looping), the first 10 % dropped (start-up)",
                          section="replay throughput")
            throughput(tmp, "C3D Movement_trial.c3d (39 markers, layout)", "mocapgraph.nodes.c3d_reader:C3DReader",
                       {"file": str(DATA / "c3d/pycgm/Movement_trial.c3d"), "layout": "plug_in_gait",
                        "rate_scale": 0.0, "loop": True}, "markers", 120.0, args.frames)
            throughput(tmp, "BVH CMU 131_01.bvh (38 joints)", "mocapgraph.nodes.bvh_player:BVHPlayer",
                       {"file": str(DATA / "bvh/cmu/131_01.bvh"), "rate_scale": 0.0, "loop": True},
                       "skeleton_pose", 120.0, args.frames)
        else:
            print(f"  skipped: {DATA} is absent")
        print(f"2. real-time replay at 240 Hz for {args.seconds:g} s (load now {os.getloadavg()[0]:.2f})")
        jitter_split = f"{int(240 * args.seconds)} frames at 240 Hz, the first 0.5 s ({int(240 * 0.5)} frames) dropped"
        print_context(None, "the marker_test_pattern node (deterministic circles, 39 markers)", jitter_split,
                      section="jitter, baseline")
        jitter(tmp, "baseline: marker_test_pattern node, 240 Hz, 39 markers (bus timers only)",
               "mocapgraph.testing.marker_pattern:MarkerTestPattern", {"rate_hz": 240.0, "n_markers": 39},
               240.0, args.seconds)
        c3d = tmp / "synthetic_240hz.c3d"
        write_240hz_c3d(c3d, args.seconds)
        print_context("1 (SyntheticActor plug_in_gait seed 1)", f"a 240 Hz C3D written here from the synthetic actor "
                      f"(plug_in_gait, frames 0-{int(240 * (args.seconds + 2)) - 1} at most), replayed looping",
                      jitter_split, section="jitter, C3D replay")
        jitter(tmp, "C3D replay, 240 Hz file, 39 markers", "mocapgraph.nodes.c3d_reader:C3DReader",
               {"file": str(c3d), "layout": "plug_in_gait", "loop": True}, 240.0, args.seconds)
        print_context("0 (the synthetic_actor node's default seed)", "the synthetic_actor node, kiip_full_body at "
                      "240 Hz, 1 mm noise", jitter_split, section="jitter, synthetic actor")
        jitter(tmp, "synthetic actor node, 240 Hz, noise 1 mm, kiip_full_body (62 markers) + ground truth",
               "mocapgraph.nodes.synthetic_actor:SyntheticActorNode",
               {"layout": "kiip_full_body", "rate_hz": 240.0, "noise_mm": 1.0}, 240.0, args.seconds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
