"""The launchers' time service on its own (two in this process, loopback): offsets measured from
real exchanges, and packets that are not the graph's counted and dropped, never answered."""
from __future__ import annotations

import select
import socket
import time
from pathlib import Path

import numpy as np

from mocapgraph.cli import main
from mocapgraph.launch.check import check_graph
from mocapgraph.launch.graph import load_graph
from mocapgraph.launch.machine_clock import BODY, MachineClocks
from mocapgraph.messages.clock_sync import PeerClock


def _ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _graph(tmp: Path, security: str) -> object:
    pa, pb = _ports(2)
    f = tmp / "split.yaml"
    f.write_text(f"""
security: {security}
nodes:
  - {{name: pattern, type: marker_test_pattern, machine: capture, host: 127.0.0.1, port: {pa}}}
  - {{name: logger, type: topic_logger, machine: render, host: 127.0.0.1, port: {pb}}}
""")
    return check_graph(load_graph(f), check_files=False)


def _exchange(a: MachineClocks, b: MachineClocks, seconds: float) -> None:
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:            # each answers as soon as its socket has a packet
        for c in (a, b):
            c.probe()
        for c in select.select([a, b], [], [], 0.01)[0]:
            c.serve()


def test_peer_clock_takes_the_exchange_of_least_delay() -> None:
    rng = np.random.default_rng(0)
    clock = PeerClock(keep=16)
    theta = 37_000_000                                   # the peer is 37 ms ahead
    for k in range(40):
        t1 = 10**18 + k * 10**8
        out, back = (50e3 + rng.exponential(2e6, 2)).astype(np.int64)   # queueing, unequal each way
        turn = int(rng.uniform(1e4, 1e6))
        t2 = t1 + out + theta
        t3 = t2 + turn
        t4 = t3 - theta + back
        clock.update(int(t1), int(t2), int(t3), int(t4))
    st = clock.stats()
    assert st.samples == 40 and abs(st.offset_ns - theta) <= st.delay_ms * 1e6 / 2
    naive = np.median(np.abs(np.array([o for _, o in clock._kept]) - theta))
    assert abs(st.offset_ns - theta) < naive                    # better than a typical exchange
    clock.update(0, 10, 5, 20)                           # answered before asked: not an exchange
    assert clock.stats().samples == 40


def test_two_services_measure_each_other_and_drop_foreign_packets(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    assert main(["keys", "generate", str(keys)]) == 0
    g = _graph(tmp_path, f"{{key: {keys / 'graph.key_secret'}, authorized: {keys}}}")
    from mocapgraph.bus.curve import CurveKeys
    secret = CurveKeys.load(str(keys / "graph.key_secret"), str(keys)).secret
    a, b = MachineClocks(g, "capture", secret), MachineClocks(g, "render", secret)
    try:
        _exchange(a, b, 0.5)
        st = a.stats()["render"]
        # one kernel clock: offset 0, as good as half the fastest round trip (NTP's bound)
        assert st.samples >= 3 and abs(st.offset_ns) <= st.delay_ms * 1e6 / 2 + 1000 and st.delay_ms < 10
        assert a.sender_offsets().keys() == {"logger"} and b.sender_offsets().keys() == {"pattern"}
        # a stranger: garbage, a request without the HMAC, a replayed answer with a wrong one
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(0.3)
            target = b.sock.getsockname()
            bare = BODY.pack(b"MGC1", b"Q", 1, 5, 0, 0)
            for pkt in (b"x" * 60, bare, bare + b"\0" * 32, b"\xff" * 200):
                s.sendto(pkt, target)
            time.sleep(0.05)
            before = b.dropped
            b.serve()
            assert b.dropped - before == 4
            try:
                s.recvfrom(256)
                answered = True
            except socket.timeout:
                answered = False
            assert not answered                                     # nothing answered to a stranger
    finally:
        a.close()
        b.close()


def test_a_machine_that_never_answers_is_named_once(tmp_path: Path) -> None:
    g = _graph(tmp_path, "{insecure: true}")
    a = MachineClocks(g, "capture")                        # render's launcher never started
    try:
        assert a.silent_peers(after_s=10.0) == []          # too early to say
        a._started -= 11.0
        for _ in range(3):
            a.probe()
            a._due = 0.0
            a.serve()
        assert [p.machine for p in a.silent_peers(after_s=10.0)] == ["render"]
        assert a.silent_peers(after_s=10.0) == []          # once
        assert a.sender_offsets() == {} and a.stats()["render"].samples == 0
    finally:
        a.close()
