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

Then the latency a reader process adds, sender to subscriber, at 240 Hz for ``--seconds``: the
``qtm_reader`` node fed by the QTM simulator over loopback TCP (62 Kiip markers, 5 bodies, a
skeleton), beside ``udp_reader`` fed the same performer's binary wire-protocol datagrams; each
node is a real process and a subscriber in this process stamps each ``markers`` message on
arrival (p50 / p99 / max of arrival minus the moment the frame was sent).

Usage: ``python benchmarks/qtm.py [--frames 5000] [--rounds 5] [--seconds 10]``.
"""
from __future__ import annotations

import argparse
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from mocapgraph.formats import qtm_rt as q
from mocapgraph.formats.device_file import DeviceConfig
from mocapgraph.formats.qtm_session import QTMToWorld

from mocapgraph.messages import decode

from _context import print_context
from _launched import reader_process, stop_reader

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


def collect(proc, sub, seconds: float) -> dict[int, int]:
    """frame number -> receive time (wall ns) of each markers message for ``seconds``."""
    got: dict[int, int] = {}
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        if sub.poll(100):
            frames = sub.recv_multipart()
            now = time.time_ns()
            got[decode(frames)[1].frame_number] = now
        elif proc.poll() is not None:
            raise SystemExit(f"reader exited: {proc.stderr.read()[-2000:]}")
    return got


def report(label: str, sent: dict[int, int], got: dict[int, int], rate: float) -> None:
    ks = sorted(k for k in got if k in sent)[int(rate):]          # the first second warms up
    lat = np.array([(got[k] - sent[k]) / 1e6 for k in ks])
    p50, p99 = np.percentile(lat, [50, 99])
    print(f"  {label:55s} p50 {p50:6.2f} ms  p99 {p99:6.2f} ms  max {lat.max():6.2f} ms  ({len(lat)} frames)")


def latency(seconds: float, rate: float = 240.0) -> None:
    from mocapgraph.formats.wire_protocol import encode_binary
    from mocapgraph.testing.device_simulator import SimulatedDevice
    from mocapgraph.testing.qtm_server import ActorQTMSource, QTMSimServer

    print(f"reader added latency, frame sent -> markers received by a subscriber, {rate:g} Hz, {seconds:g} s:")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        src = ActorQTMSource("kiip_full_body", rate, n_bodies=5)
        src.preload(2400, int((seconds + 4) * rate))          # the simulator's own work out of the timing
        srv = QTMSimServer(src, port=0, start_frame=2400).start()
        proc, sub = reader_process(tmp, "mocapgraph.nodes.qtm_reader:QTMReader", {"port": srv.port, "layout": "kiip_full_body"})
        try:
            got = collect(proc, sub, seconds + 3)
        finally:
            stop_reader(proc, sub)
            srv.stop()
        report("qtm_reader (QTM simulator, TCP, 62 markers + 5 bodies)", dict(srv.send_log), got, rate)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        proc, sub = reader_process(tmp, "mocapgraph.nodes.udp_reader:UDPReader",
                               {"port": port, "layout": "kiip_full_body", "rate_hz": rate})
        sim = SimulatedDevice("kiip_full_body", "", rate_hz=rate, start_frame=2400)
        sent: dict[int, int] = {}
        out: list[dict[int, int]] = []
        rx = threading.Thread(target=lambda: out.append(collect(proc, sub, seconds + 4.0)))
        try:
            rx.start()                                        # receives while this thread sends
            time.sleep(2.0)                                   # the node binds its port
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
                t0 = time.monotonic()
                for i, f in enumerate(sim.frames(int(seconds * rate))):
                    delay = t0 + i / rate - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                    data = encode_binary(f.frame, f.t_us, f.positions)
                    sent[f.frame] = time.time_ns()
                    tx.sendto(data, ("127.0.0.1", port))
            rx.join()
            got = out[0] if out else {}
        finally:
            stop_reader(proc, sub)
        report("udp_reader (wire protocol datagrams, 62 markers)", sent, got, rate)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=5000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=10.0, help="length of each latency run")
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
    if args.seconds > 0:
        latency(args.seconds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
