"""`mocapgraph device replay` of a QTM RT session (TCP) captured in a pcapng: the capture is built here
from the QTM simulator's own bytes (no real QTM capture exists), cut into TCP segments with a
retransmission and segments written out of order, as a capture of a real link would hold them;
the qtm_reader node fed the replay publishes every captured frame with the source's values."""
from __future__ import annotations

import struct
import subprocess
import sys

import numpy as np
import pytest

from mocapgraph.formats import qtm_rt as q
from mocapgraph.testing.pcapng import write_ip
from mocapgraph.testing.qtm_replay import capture_qtm
from mocapgraph.testing.qtm_server import ActorQTMSource, encode_components

pytestmark = pytest.mark.slow
SERVER, CLIENT = ("10.0.0.2", 22223), ("10.0.0.9", 50123)
START, N, RATE = 600, 48, 120.0


def tcp(src, dst, seq: int, payload: bytes) -> bytes:
    """An IPv4 + TCP packet (checksums left 0: the reader does not check them, as a capture of
    checksum-offloading hardware shows them)."""
    ip = lambda a: bytes(int(x) for x in a.split("."))  # noqa: E731
    th = struct.pack(">HHIIBBHHH", src[1], dst[1], seq, 0, 5 << 4, 0x18, 65535, 0, 0)
    return struct.pack(">BBHHHBBH4s4s", 0x45, 0, 40 + len(payload), 0, 0, 64, 6, 0, ip(src[0]), ip(dst[0])) + th + payload


def session_capture(path, src: ActorQTMSource) -> list[bytes]:
    """A pcapng of what a QTM server sent a client: welcome, version reply, parameters XML, N data
    packets at the frame rate. Returns the data packets."""
    t0 = 1_700_000_000_000_000_000
    talk = [q.encode_string(q.PACKET_COMMAND, q.WELCOME), q.encode_string(q.PACKET_COMMAND, "Version set to 1.25"),
            q.encode_string(q.PACKET_XML, src.parameters("1.25", ("general", "3d", "6d", "skeleton")))]
    data = [q.encode_data(k, round((k - START) * 1e6 / RATE),
                          encode_components(src.frame(k), ("3dres", "3dnolabels", "6dres", "skeleton:global"), RATE))
            for k in range(START, START + N)]
    stream = [(t0, p) for p in talk] + [(t0 + 50_000_000 + round(i * 1e9 / RATE), p) for i, p in enumerate(data)]
    packets, seq = [], 1000
    for t, p in stream:
        cut = len(p) // 3 if len(p) > 300 else len(p)           # long packets in two segments
        for part in (p[:cut], p[cut:]):
            if part:
                packets.append((t, tcp(SERVER, CLIENT, seq, part)))
                seq += len(part)
    packets.insert(10, (packets[9][0] + 1000, packets[9][1]))    # a retransmission
    packets[20], packets[21] = packets[21], packets[20]          # two segments captured out of order
    packets.insert(5, (t0 + 1, tcp(CLIENT, SERVER, 1, b"\x00\x00\x00\x11\x00\x00\x00\x01Version 1.25\x00")))
    write_ip(path, packets)
    return data


def test_a_captured_qtm_session_replays_to_the_reader(run_node, tmp_path) -> None:
    src = ActorQTMSource("plug_in_gait", RATE, n_bodies=2, occlude_every=5)
    path = tmp_path / "qtm.pcapng"
    data = session_capture(path, src)
    cap = capture_qtm(path)
    assert cap.server == SERVER and [p for _, p in cap.frames] == data          # reassembled exactly
    np.testing.assert_allclose(np.diff([t for t, _ in cap.frames]), 1 / RATE, atol=1e-6)   # s since 1970: 0.2 us steps
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "device", "replay", str(path), "--port", "0",
                             "--wait", "20"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert f"replaying {N} QTM frames" in line, line + proc.stderr.read()
        port = int(line.rsplit("port:=", 1)[1].rstrip(")\n"))
        n = run_node("qtm_reader", {"port": port, "layout": "plug_in_gait"})
        recs = n.wait_for(lambda: n.records("markers") if len(n.records("markers")) >= N else None, 20,
                          f"{N} frames")
        assert proc.wait(20) == 0, proc.stderr.read()
    finally:
        proc.kill()
    assert [r.msg.frame_number for r in recs] == list(range(START, START + N))
    want = np.array([src.frame(k).markers for k in range(START, START + N)], float) / 1000.0   # +Z up: world
    got = np.array([r.msg.positions for r in recs])
    np.testing.assert_allclose(got, want, atol=1e-6, equal_nan=True)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isnan(want).any()
    bodies = n.messages("rigid_bodies")[-N:]
    assert [b.frame_number for b in bodies] == list(range(START, START + N))
    assert n.messages("skeleton_pose")[-1].frame_number == START + N - 1
