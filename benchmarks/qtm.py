"""QTM RT decode cost per frame (60 labelled markers + 5 6DOF bodies + a 20-segment skeleton +
timecode) beside a raw socket receive of the same packets in the same run, and beside Qualisys's
own ``qtm-rt`` parser on the same bytes.

Figures, µs per frame (median of ``--rounds`` rounds of ``--frames`` frames):

1. raw receive: the packets written to a loopback TCP socket pair and read back in 64 KB chunks
   (what the reader's socket read costs before any decoding);
2. split + decode: :class:`PacketSplitter` and :func:`decode_data` (all components to arrays);
3. the reader's per-frame math after decoding: mm -> m and QTM axes -> world (a +Y-up QTM, so the
   rotation is applied), rotation matrices -> quaternions, skeleton quaternions reordered;
4. qtm-rt (if installed): ``QRTPacket`` plus reading the 3D, 6D, skeleton and timecode components.

Usage: ``python benchmarks/qtm.py [--frames 5000] [--rounds 5]``.
"""
from __future__ import annotations

import argparse
import socket
import time

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.formats import qtm_rt as q
from mocapgraph.formats.device_file import DeviceConfig
from mocapgraph.formats.qtm_session import QTMToWorld

from _context import print_context

N_MARKERS, N_BODIES, N_SEGMENTS = 60, 5, 20


def packets(n: int, seed: int = 0) -> list[bytes]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        mm = rng.normal(0, 500, (N_MARKERS, 3)).astype(np.float32)
        mm[k % N_MARKERS] = np.nan
        R = Rotation.random(N_BODIES, random_state=k).as_matrix()
        quat = Rotation.random(N_SEGMENTS, random_state=k + 1).as_quat().astype(np.float32)
        comps = [q.component_3d(mm, np.full(N_MARKERS, 0.7, np.float32)),
                 q.component_3d_no_labels(mm[:4], np.arange(4, dtype=np.int32)),
                 q.component_6d(mm[:N_BODIES], R.transpose(0, 2, 1).reshape(N_BODIES, 9).astype(np.float32),
                                np.full(N_BODIES, 0.4, np.float32)),
                 q.component_skeletons([q.Skeleton(np.arange(1, N_SEGMENTS + 1, dtype=np.int32),
                                                   mm[:N_SEGMENTS], quat)]),
                 q.component_timecodes([(q.TIMECODE_SMPTE, q.smpte(k, 240.0), 0), (q.TIMECODE_CAMERA, 0, k)])]
        out.append(q.encode_data(k, k * 4167, comps))
    return out


def per_frame_us(fn, n: int) -> float:
    t = time.perf_counter()
    fn()
    return (time.perf_counter() - t) / n * 1e6


def raw_receive(blob: bytes) -> None:
    a, b = socket.socketpair()
    a.setblocking(False)
    sent = got = 0
    while got < len(blob):
        if sent < len(blob):
            try:
                sent += a.send(blob[sent:sent + (1 << 20)])
            except BlockingIOError:
                pass
        got += len(b.recv(65536))
    a.close()
    b.close()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print_context("0 (np.random.default_rng: marker positions; scipy Rotation.random(k): orientations)",
                  f"{args.frames} synthetic QTM data packets encoded by mocapgraph.formats.qtm_rt")
    pk = packets(args.frames)
    blob = b"".join(pk)
    dev = DeviceConfig().with_up_axis("+Y")
    w = QTMToWorld(dev)
    decoded = [q.decode_data(p[8:]) for p in pk]

    def split_decode() -> None:
        sp = q.PacketSplitter()
        for i in range(0, len(blob), 65536):
            for _t, payload in sp.feed(blob[i:i + 65536]):
                q.decode_data(payload)

    def world() -> None:
        for f in decoded:
            w.points(f.markers)
            w.points(f.body_positions)
            w.body_quats(f.body_rotations)
            w.points(f.skeletons[0].positions)
            w.segment_quats(f.skeletons[0].quats_xyzw)

    cases = [("raw loopback TCP receive", lambda: raw_receive(blob)), ("split + decode (ours)", split_decode),
             ("reader math after decode (mm->m, axes, quaternions)", world)]
    try:
        from qtm_rt.packet import QRTPacket

        def ref() -> None:
            for p in pk:
                r = QRTPacket(p[8:])
                r.get_3d_markers_residual(), r.get_6d_residual(), r.get_skeletons(), r.get_timecode()
        cases.append(("qtm-rt QRTPacket + component getters", ref))
    except ImportError:
        print("qtm-rt not installed: its parser is not timed")
    print(f"{args.frames} frames of {len(pk[0])} bytes: {N_MARKERS} labelled markers (+4 unlabelled), "
          f"{N_BODIES} 6DOF bodies, a {N_SEGMENTS}-segment skeleton, 2 timecodes")
    for name, fn in cases:
        us = sorted(per_frame_us(fn, args.frames) for _ in range(args.rounds))
        print(f"  {name:55s} {us[len(us) // 2]:8.2f} us/frame (min {us[0]:.2f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
