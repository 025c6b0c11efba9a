"""Cost of the avatar outputs (issue #29): a VMC bundle per pose, a glTF export, a glTF character read back.

Prints: a VMC bundle (our python-osc template filled with numpy) per character, beside building
every message of the same bundle with python-osc's builders, us/frame and the share of a core at
240 Hz; `retarget -o out.glb`'s writer on a 994-frame take (CMU 131_01's length) onto Mixamo with
the generated mannequin, seconds and MB; the mannequin alone; reading the file back as a
character; and a launched graph (synthetic_character, standard_20 at 240 Hz -> vmc_outlet -> a UDP
socket here): bundles received per second and the vmc_outlet process's CPU (/proc). Compare ratios,
not times (the machine is shared).
Run: .venv/bin/python benchmarks/avatar_outputs.py [--frames 994] [--graph-seconds 10]
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder

from mocapgraph.formats.character_file import load_character
from mocapgraph.formats.gltf_character import load_gltf_character
from mocapgraph.formats.gltf_export import write_gltf
from mocapgraph.formats.mannequin import mannequin
from mocapgraph.formats.vmc import VMCBundle

from _context import print_context


def _best(fn, n: int) -> float:
    best = np.inf
    for _ in range(3):
        t0 = time.perf_counter()
        for i in range(n):
            fn(i)
        best = min(best, (time.perf_counter() - t0) / n)
    return best


def _random_take(ch, frames: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    v = rng.normal(scale=0.4, size=(frames, ch.n_joints, 3))
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    q = np.concatenate([np.cos(angle / 2), np.sin(angle / 2) * v / np.maximum(angle, 1e-12)], axis=-1)
    return q, rng.normal(scale=0.3, size=(frames, 3)) + [0, 0, 1]


def vmc(name: str) -> None:
    ch = load_character(name)
    vb = VMCBundle(ch)
    q, root = _random_take(ch, 64, 0)
    quality = np.full(ch.n_joints, 2)
    ours = _best(lambda i: vb.encode(q[i % 64], root[i % 64], quality, i / 60), 500)

    def builders(i: int) -> bytes:
        rp, lp, lq = vb.unity_pose(q[i % 64], root[i % 64])
        bb = OscBundleBuilder(IMMEDIATELY)
        for addr, args in ([("/VMC/Ext/OK", [1, 3, 0, 1]), ("/VMC/Ext/T", [i / 60]),
                            ("/VMC/Ext/Root/Pos", ["root", *rp.tolist(), 0.0, 0.0, 0.0, 1.0])]
                           + [("/VMC/Ext/Bone/Pos", [b, *p, *r]) for b, p, r in
                              zip(vb.bone_names, lp.tolist(), lq.tolist())]):
            mb = OscMessageBuilder(addr)
            for a in args:
                mb.add_arg(a)
            bb.add_content(mb.build())
        return bb.build().dgram

    theirs = _best(builders, 200)
    size = len(vb.encode(q[0], root[0], quality, 0.0))
    print(f"VMC bundle, {name:11s} ({len(vb.bone_names):2d} bones, {size} B): ours {ours * 1e6:6.1f} us/frame, "
          f"python-osc builders {theirs * 1e6:6.1f} us/frame -> {theirs / ours:4.1f}x; at 240 Hz ours is "
          f"{100 * ours * 240:.1f} % of a core")


def gltf(frames: int) -> None:
    ch = load_character("mixamo")
    q, root = _random_take(ch, frames, 1)
    t0 = time.perf_counter()
    mesh = mannequin(ch)
    t_mesh = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "take.glb"
        t0 = time.perf_counter()
        n = write_gltf(out, ch, q, root, np.arange(frames) / 120, mesh=mesh)
        t_write = time.perf_counter() - t0
        t0 = time.perf_counter()
        back = load_gltf_character(out)
        t_read = time.perf_counter() - t0
    print(f"mannequin of mixamo: {len(mesh.positions)} vertices, {len(mesh.triangles)} triangles in "
          f"{t_mesh * 1000:.1f} ms")
    print(f"glTF export, mixamo x {frames} frames + mannequin: {t_write:.3f} s, {n / 1e6:.2f} MB "
          f"({frames / t_write:.0f} frames/s)")
    print(f"glTF character read back (skin, mesh): {t_read * 1000:.1f} ms, {back.character.n_joints} joints, "
          f"{len(back.mesh.positions)} vertices")


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def graph(seconds: float) -> None:
    import socket
    from _launched import launched_graph
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(0.2)
    yaml = f"""
nodes:
  - name: dancer
    type: synthetic_character
    params: {{rate_hz: 240.0}}
  - name: vmc
    type: vmc_outlet
    params: {{port: {rx.getsockname()[1]}}}
"""
    with tempfile.TemporaryDirectory() as tmp, launched_graph(yaml, "character_pose", Path(tmp)) as manifest:
        pid = next(n["pid"] for n in manifest["nodes"] if n["name"] == "vmc")
        t_end = time.monotonic() + 2.0
        while time.monotonic() < t_end:            # warm-up
            try:
                rx.recv(65536)
            except socket.timeout:
                pass
        n, c0, t0 = 0, _cpu_s(pid), time.monotonic()
        while time.monotonic() < t0 + seconds:
            try:
                rx.recv(65536)
                n += 1
            except socket.timeout:
                pass
        cpu = 100 * (_cpu_s(pid) - c0) / (time.monotonic() - t0)
    rx.close()
    print(f"vmc_outlet in a graph, standard_20 at 240 Hz, {seconds:g} s: {n / seconds:.1f} bundles/s received, "
          f"node CPU {cpu:.1f} % of a core")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=994)
    ap.add_argument("--graph-seconds", type=float, default=10.0)
    args = ap.parse_args()
    print_context("0 (np.random.default_rng: rotation vectors N(0, 0.4), roots N(0, 0.3))",
                  "generated poses of the shipped characters (mixamo, cmu, standard_20)", section="VMC")
    for name in ("standard_20", "cmu", "mixamo"):
        vmc(name)
    print_context("1 (np.random.default_rng: rotation vectors N(0, 0.4), roots N(0, 0.3))",
                  f"a generated {args.frames}-frame take onto mixamo at 120 Hz", section="glTF")
    gltf(args.frames)
    if args.graph_seconds > 0:
        print_context(None, "synthetic_character (standard_20, the synthetic performer's walk) at 240 Hz",
                      section="graph")
        graph(args.graph_seconds)


if __name__ == "__main__":
    main()
