"""Parsing speed of the file formats on the shared captures, in frames per second.

Run: .venv/bin/python benchmarks/formats_speed.py [--repeat N]
Prints one line per file: frames, best wall time over N runs, frames/s (C3D also as a ratio to a
bare ezc3d read in the same run), a generated ROTATION-group C3D, and the graph check with and
without its input-file checks. Files absent from ../shared/data are skipped.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import ezc3d
import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.formats import read_bvh, read_c3d, read_c3d_segments, read_kinect_csv, read_trc
from mocapgraph.formats.wire_protocol import BinaryDecoder, TextDecoder, encode_binary, encode_text

from _context import print_context

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
    print_context(None, f"the real captures under {DATA} (c3d/, trc/, bvh/, the first 2 kinect2/*.csv; absent files "
                  "skipped)", f"every frame of each file, best of {n} runs", section="files")
    for rel in ["c3d/pycgm/Static_trial.c3d", "c3d/pycgm/Movement_trial.c3d",
                "c3d/ezc3d-testFiles/Qualisys.c3d", "c3d/ezc3d-testFiles/BTS.c3d",
                "c3d/ezc3d-testFiles/FP_Type1.c3d", "c3d/btkdata/golfswing.c3d"]:
        p = DATA / rel
        if p.exists():
            t, tr = best_of(lambda: read_c3d(p), n)
            line(f"read_c3d {p.name} ({tr.extra['backend']})", tr.n_frames, t)
            if tr.extra["backend"] == "ezc3d":  # baseline: the bare library read, same run
                t0, _ = best_of(lambda: ezc3d.c3d(str(p)), n)
                print(f"  {'':<42} x{t / t0:5.2f} of a bare ezc3d.c3d() ({t0 * 1e3:.2f} ms): checks + conversions")
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

    segments_and_graph_check(n)

    print_context("0 (np.random.default_rng: marker positions)", "2000 generated frames of 40 markers, U(-2, 2) m, "
                  "encoded in this run", f"every frame, cut into 1400-byte chunks; best of {n} runs", section="wire")
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


def segments_and_graph_check(n: int) -> None:
    """A C3D ROTATION group (20 segments x 3000 frames, written here) and the graph check's cost
    of checking input files, against the same check without them."""
    from mocapgraph.launch.check import check_graph
    from mocapgraph.launch.graph import load_graph

    print_context("1 (np.random.default_rng: Rotation.random(random_state=rng) and the translations)",
                  "a generated C3D with a ROTATION group, 20 segments x 3000 frames at 120 Hz, written in this run",
                  f"every frame, best of {n} runs", section="segments")
    with tempfile.TemporaryDirectory() as d:
        T, S = 3000, 20
        rng = np.random.default_rng(1)
        R = Rotation.random(T * S, random_state=rng).as_matrix().reshape(T, S, 3, 3)
        rot = np.tile(np.eye(4), (T, S, 1, 1))
        rot[..., :3, :3] = R
        rot[..., :3, 3] = rng.uniform(-1000, 1000, (T, S, 3))
        c = ezc3d.c3d()
        c["parameters"]["POINT"]["RATE"]["value"] = [120.0]
        c["data"]["points"] = np.zeros((4, 0, T))
        c["data"]["rotations"] = rot.transpose(2, 3, 1, 0)
        c.add_parameter("ROTATION", "USED", S)
        c.add_parameter("ROTATION", "LABELS", [f"seg{k}" for k in range(S)])
        c.add_parameter("ROTATION", "RATE", 120.0)
        path = Path(d) / "segments.c3d"
        c.write(str(path))
        t0, _ = best_of(lambda: ezc3d.c3d(str(path)), n)
        t, sk = best_of(lambda: read_c3d_segments(path), n)
        line(f"read_c3d_segments ({S} segments)", sk.n_frames, t)
        print(f"  {'':<42} x{t / t0:5.2f} of a bare ezc3d.c3d() ({t0 * 1e3:.2f} ms)")
    graph = Path(__file__).resolve().parents[1] / "graph_configs" / "lab_c3d.yaml"
    if (DATA / "c3d/pycgm/Movement_trial.c3d").exists():
        print_context(None, "graph_configs/lab_c3d.yaml, its default capture "
                      "../shared/data/c3d/pycgm/Movement_trial.c3d",
                      f"the whole graph check, best of {n} runs", section="graph check")
        spec = load_graph(graph)
        t_off, _ = best_of(lambda: check_graph(spec, check_files=False), n)
        t_on, _ = best_of(lambda: check_graph(spec), n)
        print(f"graph check lab_c3d.yaml: {t_on * 1e3:.2f} ms with input files checked, "
              f"{t_off * 1e3:.2f} ms without (x{t_on / t_off:.2f})")


if __name__ == "__main__":
    main()
