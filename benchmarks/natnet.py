"""NatNet reader cost per frame at 60 markers + 5 rigid bodies, beside a raw socket receive in the same run.

Run: .venv/bin/python benchmarks/natnet.py [--frames N] [--seconds S]
1. Per NatNet version (3.0, 4.1), microseconds per frame for: receiving the datagram on a loopback
   UDP socket (the floor any reader pays), decoding it (formats.natnet.decode_frame), and the
   reader's whole per-frame path short of the bus send (decode, labels and bodies in layout order,
   Motive axes to world, the three messages built and encoded). Frames: the synthetic actor wearing
   the Qualisys layout (55 labelled markers) with 5 unlabelled markers and 5 rigid bodies.
2. Live, 240 Hz for ``--seconds``: the natnet_reader node process fed by our NatNet server (62
   markers of kiip_full_body, 5 rigid bodies), beside the udp_reader node process fed the same
   markers as wire-protocol datagrams: frames received of sent, gaps, and the latency from the
   datagram's send to a bus subscriber's receive of its MarkerFrame (p50, p99, max).
"""
from __future__ import annotations

import argparse
import socket
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from mocapgraph.formats import natnet as nn
from mocapgraph.formats import natnet_encode as ne
from mocapgraph.formats.device_file import device_or_default
from mocapgraph.formats.natnet_model import NatNetModel, device_time_ns, rotation_quat, unlabelled
from mocapgraph.kinematics.quaternion import quat_multiply
from mocapgraph.messages.clock_sync import ClockSync
import zmq

from mocapgraph.formats.wire_protocol import encode_binary
from mocapgraph.messages import MarkerFrame, RigidBodyFrame, decode, encode
from mocapgraph.nodes.marker_source import LayoutMap
from mocapgraph.testing.natnet_server import ActorStream, NatNetServer

from _context import print_context
from _launched import reader_process, stop_reader


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
    clock = ClockSync()

    def run(packet: bytes) -> None:
        f = nn.decode_frame(packet, version)
        device_ns, latency_ns = device_time_ns(f, 10_000_000)
        cap = clock.update(device_ns, time.time_ns(), latency_ns)
        lab, bodies = model.labelled(f), model.bodies(f)
        pos = lmap.positions(dev.points_to_world(lab.positions))
        m = MarkerFrame(frame_number=f.frame_number, rate_hz=240.0, positions=pos, valid=~np.isnan(pos).any(axis=1),
                        residual=lmap.values(lab.residual, np.nan))
        upos, ures = unlabelled(f)
        u = MarkerFrame(frame_number=f.frame_number, rate_hz=240.0, positions=dev.points_to_world(upos),
                        valid=np.ones(len(upos), bool), residual=ures)
        b = RigidBodyFrame(frame_number=f.frame_number, positions=dev.points_to_world(bodies.positions),
                           orientations=quat_multiply(dev_q, bodies.quat_wxyz), error=bodies.error,
                           quality=np.where(bodies.valid, 2, 0).astype(np.int8))
        for topic, msg in (("markers", m), ("unlabelled_markers", u), ("rigid_bodies", b)):
            encode(topic, msg, 1, cap)
    return run


def live(label: str, proc: subprocess.Popen, sub: zmq.Socket, send, n: int, rate: float) -> None:
    """Send ``n`` frames at ``rate`` from a thread (``send(k)`` sends frame k), receive on ``sub``."""
    sent = np.zeros(n, np.int64)
    got: dict[int, int] = {}

    def sender() -> None:
        t0 = time.monotonic()
        for k in range(n):
            delay = t0 + k / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            sent[k] = time.time_ns()
            send(k)

    th = threading.Thread(target=sender, daemon=True)
    th.start()
    end = time.monotonic() + n / rate + 5
    try:
        while time.monotonic() < end and len(got) < n:
            if sub.poll(100):
                frames = sub.recv_multipart()
                now = time.time_ns()
                _, msg = decode(frames)
                got[msg.frame_number] = now
    finally:
        th.join(5)
        stop_reader(proc, sub)
    ks = np.array(sorted(k for k in got if 0 <= k < n))
    lat = (np.array([got[k] for k in ks]) - sent[ks]) / 1e6 if len(ks) else np.zeros(1)
    gaps = int(np.sum(np.diff(ks) - 1)) if len(ks) > 1 else 0
    print(f"{label:<34}{len(ks):>6} of {n:<6}{gaps:>6}{np.percentile(lat, 50):>9.2f}{np.percentile(lat, 99):>9.2f}"
          f"{lat.max():>9.2f}")


def live_section(seconds: float) -> None:
    rate, n = 240.0, int(seconds * 240)
    stream = ActorStream("kiip_full_body", rate_hz=rate, n_bodies=5, n_unlabelled=0, seed=0, skeleton=False)
    print_context(0, "synthetic actor kiip_full_body seed 0 (62 markers, 5 rigid bodies)",
                  f"frames 0..{n - 1} at 240 Hz over loopback", section="live")
    print(f"{'reader (240 Hz)':<34}{'frames':>16}{'gaps':>6}{'p50 ms':>9}{'p99 ms':>9}{'max ms':>9}")
    version = (4, 1)
    frames = [ne.frame(f, version) for f in stream.frames(0, n)]
    with tempfile.TemporaryDirectory() as tmp:
        server = NatNetServer(ne.server_info(stream.server_info(version)),
                              ne.model_defs(stream.model_defs(), version), command_port=0, rate_hz=rate)
        proc, sub = reader_process(Path(tmp), "mocapgraph.nodes.natnet_reader:NatNetReader",
                                 {"server": "127.0.0.1", "command_port": server.command_port, "silence_s": 30.0})
        end = time.monotonic() + 30
        while not (server.clients and server.requests.get(nn.NAT_REQUEST_MODELDEF)) and time.monotonic() < end:
            server.serve()
            time.sleep(0.005)
        time.sleep(0.3)
        server.serve()
        live("natnet_reader (NatNet 4.1)", proc, sub, lambda k: server.send(frames[k]), n, rate)
        server.close()
        markers = stream.world(0, n)[0]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        proc, sub = reader_process(Path(tmp), "mocapgraph.nodes.udp_reader:UDPReader", {"port": port, "layout": ""})
        time.sleep(1.5)  # no handshake to wait on: let it bind
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        live("udp_reader (wire protocol)", proc, sub,
             lambda k: tx.sendto(encode_binary(k, round(k * 1e6 / rate), np.nan_to_num(markers[k])),
                                 ("127.0.0.1", port)), n, rate)
        tx.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=2000)
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    n = args.frames
    stream = ActorStream("qualisys", rate_hz=240.0, n_bodies=5, n_unlabelled=5, dropout_rate_hz=0.2, seed=0,
                         skeleton=False)
    print_context(0, "synthetic actor qualisys seed 0 (55 labelled + 5 unlabelled markers, 5 rigid bodies, "
                  "occlusions 0.2/marker/s)", f"frames 0..{n - 1} at 240 Hz, best of 3 passes", section="cost")
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
    if args.seconds > 0:
        live_section(args.seconds)


if __name__ == "__main__":
    main()
