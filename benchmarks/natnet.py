"""NatNet reader cost per frame at 60 markers + 5 rigid bodies, beside a raw socket receive in the same run.

Run: .venv/bin/python benchmarks/natnet.py [--frames N]
Prints, per NatNet version (3.0, 4.1), microseconds per frame for: receiving the datagram on a
loopback UDP socket (the floor any reader pays), decoding it (formats.natnet.decode_frame), and the
reader's whole per-frame path short of the bus send (decode, labels and bodies in layout order,
Motive axes to world, the three messages built and encoded). Frames: the synthetic actor wearing
the Qualisys layout (55 labelled markers) with 5 unlabelled markers and 5 rigid bodies.
"""
from __future__ import annotations

import argparse
import socket
import time

import numpy as np

from mocapgraph.formats import natnet as nn
from mocapgraph.formats import natnet_encode as ne
from mocapgraph.formats.device_file import device_or_default
from mocapgraph.formats.natnet_model import NatNetModel, capture_time_ns, rotate_quats, rotation_quat, unlabelled
from mocapgraph.messages import MarkerFrame, RigidBodyFrame, encode
from mocapgraph.nodes.marker_source import LayoutMap
from mocapgraph.testing.natnet_server import ActorStream

from _context import print_context


def per_frame_us(fn, packets: list[bytes], repeat: int = 3) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        for p in packets:
            fn(p)
        best = min(best, time.perf_counter() - t0)
    return best / len(packets) * 1e6


def socket_receive_us(packets: list[bytes], batch: int = 32) -> float:
    """Send packets over loopback in batches (within the socket buffer), timing the recvfrom of each."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    best = float("inf")
    for _ in range(3):
        spent = 0.0
        for k in range(0, len(packets), batch):
            chunk = packets[k:k + batch]
            for p in chunk:
                tx.sendto(p, rx.getsockname())
            t0 = time.perf_counter()
            for _ in chunk:
                rx.recvfrom(65536)
            spent += time.perf_counter() - t0
        best = min(best, spent)
    rx.close()
    tx.close()
    return best / len(packets) * 1e6


def reader_path(version: nn.Version, model: NatNetModel, lmap: LayoutMap, dev):
    dev_q = rotation_quat(dev.rotation)

    def run(packet: bytes) -> None:
        f = nn.decode_frame(packet, version)
        cap = capture_time_ns(time.time_ns(), f, 10_000_000)
        lab, bodies = model.labelled(f), model.bodies(f)
        pos = lmap.positions(dev.points_to_world(lab.positions))
        m = MarkerFrame(frame_number=f.frame_number, rate_hz=240.0, positions=pos, valid=~np.isnan(pos).any(axis=1),
                        residual=lmap.values(lab.residual, np.nan))
        upos, ures = unlabelled(f)
        u = MarkerFrame(frame_number=f.frame_number, rate_hz=240.0, positions=dev.points_to_world(upos),
                        valid=np.ones(len(upos), bool), residual=ures)
        b = RigidBodyFrame(frame_number=f.frame_number, positions=dev.points_to_world(bodies.positions),
                           orientations=rotate_quats(dev_q, bodies.quat_wxyz), error=bodies.error,
                           quality=np.where(bodies.valid, 2, 0).astype(np.int8))
        for topic, msg in (("markers", m), ("unlabelled_markers", u), ("rigid_bodies", b)):
            encode(topic, msg, 1, cap)
    return run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    n = ap.parse_args().frames
    stream = ActorStream("qualisys", rate_hz=240.0, n_bodies=5, n_unlabelled=5, dropout_rate_hz=0.2, seed=0)
    print_context(0, "synthetic actor qualisys seed 0 (55 labelled + 5 unlabelled markers, 5 rigid bodies, "
                  "occlusions 0.2/marker/s)", f"frames 0..{n - 1} at 240 Hz, best of 3 passes")
    frames = list(stream.frames(0, n))
    dev = device_or_default("", "y")
    print(f"{'NatNet':<8}{'bytes':>7}{'socket recv':>14}{'decode':>10}{'reader path':>14}{'path/recv':>11}  (us/frame)")
    for version in ((3, 0), (4, 1)):
        packets = [ne.frame(f, version) for f in frames]
        model = NatNetModel(nn.decode_model_defs(ne.model_defs(stream.model_defs(), version), version))
        lmap = LayoutMap.build("qualisys", model.labels)
        recv = socket_receive_us(packets)
        dec = per_frame_us(lambda p: nn.decode_frame(p, version), packets)
        path = per_frame_us(reader_path(version, model, lmap, dev), packets)
        print(f"{'%d.%d' % version:<8}{len(packets[0]):>7}{recv:>14.1f}{dec:>10.1f}{path:>14.1f}{path / recv:>11.1f}")
    print(f"at 240 Hz a frame is {1e6 / 240:.0f} us apart")


if __name__ == "__main__":
    main()
