"""Parsing speed of the file formats on the shared captures, in frames per second.

Run: .venv/bin/python benchmarks/formats_speed.py [--repeat N]
Prints one line per file: frames, best wall time over N runs, frames/s. Files absent from
../shared/data are skipped.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mocapgraph.formats import read_bvh, read_c3d, read_kinect_csv, read_trc
from mocapgraph.formats.wire_protocol import BinaryDecoder, TextDecoder, encode_binary, encode_text

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def best_of(fn, repeat: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def line(what: str, frames: int, seconds: float) -> None:
    print(f"{what:<44} {frames:>6} frames {seconds * 1e3:9.2f} ms {frames / seconds:>12,.0f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    n = ap.parse_args().repeat
    print(f"data: {DATA}")
    for rel in ["c3d/pycgm/Static_trial.c3d", "c3d/pycgm/Movement_trial.c3d",
                "c3d/ezc3d-testFiles/Qualisys.c3d", "c3d/ezc3d-testFiles/BTS.c3d",
                "c3d/ezc3d-testFiles/FP_Type1.c3d", "c3d/btkdata/golfswing.c3d"]:
        p = DATA / rel
        if p.exists():
            t, tr = best_of(lambda: read_c3d(p), n)
            line(f"read_c3d {p.name} ({tr.extra['backend']})", tr.n_frames, t)
    for rel in ["trc/opensim-gait2392/subject01_static.trc",
                "trc/opensim-gait2392/subject01_walk1.trc"]:
        p = DATA / rel
        if p.exists():
            t, tr = best_of(lambda: read_trc(p), n)
            line(f"read_trc {p.name}", tr.n_frames, t)
    for rel in ["bvh/cmu/131_01.bvh", "bvh/mixamo/test_freebvh.bvh"]:
        p = DATA / rel
        if p.exists():
            t, m = best_of(lambda: read_bvh(p), n)
            line(f"read_bvh {p.name}", m.n_frames, t)
            t, _ = best_of(m.forward_kinematics, n)
            line(f"  forward_kinematics ({m.n_joints} joints)", m.n_frames, t)
    for p in sorted((DATA / "kinect2").glob("*.csv"))[:2]:
        t, sk = best_of(lambda: read_kinect_csv(p), n)
        line(f"read_kinect_csv {p.name}", sk.n_frames, t)

    rng = np.random.default_rng(0)
    frames = [(k, k * 8333, rng.uniform(-2, 2, (40, 3))) for k in range(2000)]
    for name, enc, dec in (("text", encode_text, TextDecoder), ("binary", encode_binary, BinaryDecoder)):
        blob = b"".join(enc(*f) for f in frames)
        chunks = [blob[i:i + 1400] for i in range(0, len(blob), 1400)]  # UDP-sized pieces

        def decode_all(dec=dec, chunks=chunks) -> int:
            d = dec()
            return sum(len(d.feed(c)) for c in chunks)

        t, got = best_of(decode_all, n)
        assert got == len(frames)
        line(f"wire decode {name}, 40 markers, 1400-byte chunks", len(frames), t)


if __name__ == "__main__":
    main()
