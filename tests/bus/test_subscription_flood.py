"""A peer that floods a publisher with subscriptions costs it neither memory nor its stream's timing.

ZeroMQ's XPUB keeps every subscription a peer sends (a trie of prefixes per peer) unless the
application takes them in hand; the node's XPUB runs in manual mode and applies only
subscriptions to the topics it publishes (each once per peer: the trie holds at most one entry
per own topic per peer), and a peer that sends more than a subscriber ever does is cut off
(`bus.peer_guard`). Here one peer sends 200 000 distinct subscriptions (212 bytes, as in the
report that found it, and 16) while an observer times the publisher's stream.
"""
from __future__ import annotations

import os
import time

import numpy as np
import pytest
import zmq

from graph_helpers import node_pids, wait_until
from mocapgraph.bus.manifest import fetch_manifest, subscribe
from mocapgraph.messages import decode_envelope

pytestmark = pytest.mark.timing  # judged on time: run loaded by scripts/loaded_rounds.sh

RATE_HZ = 100.0
N_SUBS = int(os.environ.get("FLOOD_N", 200_000))
SUB_BYTES = 212


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def _cpu_s(pid: int) -> float:
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _stamps(sock: zmq.Socket, for_s: float) -> list[int]:
    """Publish stamps (the sender's clock, ns) of the messages arriving within ``for_s`` s (at least
    those queued now): when the publisher sent, whatever our own delays in reading."""
    out = []
    t_end = time.monotonic() + for_s
    while True:
        while True:
            try:
                out.append(decode_envelope(sock.recv_multipart(zmq.NOBLOCK)).publish_ns)
            except zmq.Again:
                break
        if time.monotonic() >= t_end:
            return out
        sock.poll(20)


@pytest.mark.parametrize("sub_bytes", [SUB_BYTES, 16])
def test_200000_subscriptions_from_one_peer_leave_memory_and_stream_alone(launch_graph, sub_bytes: int) -> None:
    """212 bytes: longer than any subscription the publisher serves, ZeroMQ drops the peer at its
    first; 16 bytes: as short as a real one, the guard cuts the peer off."""
    g = launch_graph(f"""
nodes:
  - name: pattern
    type: marker_test_pattern
    params: {{rate_hz: {RATE_HZ}, n_markers: 8}}
  - name: logger
    type: topic_logger
    params: {{path: log.jsonl, topics: [marker_layout]}}
""")
    g.wait_ready()
    manifest = fetch_manifest(g.master)
    endpoint = manifest["topics"]["markers"]["publishers"][0]["endpoint"]
    observer = subscribe(manifest, ["markers"])
    wait_until(lambda: observer.poll(100), 20, "markers flowing", g)
    pid = node_pids(g)["pattern"]
    _stamps(observer, 1.5)
    rss0 = _rss_mb(pid)
    cpu0 = _cpu_s(pid)
    flood = zmq.Context.instance().socket(zmq.XSUB)   # raw subscription messages, as a hostile peer sends them
    flood.setsockopt(zmq.SNDHWM, 0)
    flood.setsockopt(zmq.LINGER, 0)
    flood.setsockopt(zmq.RECONNECT_IVL, -1)   # one peer, one connection
    flood.connect(endpoint)
    time.sleep(0.3)
    pad = b"j" * (sub_bytes - 1 - 7)
    t0 = time.monotonic()
    times: list[int] = []
    for i in range(N_SUBS):
        flood.send(b"\x01%07d" % i + pad)   # 212 bytes each, all distinct
        if i % 5000 == 4999:
            times += _stamps(observer, 0.0)
    times += _stamps(observer, 4.0)
    flood_s = time.monotonic() - t0
    rss1 = _rss_mb(pid)
    cpu = _cpu_s(pid) - cpu0
    times = np.asarray(times, np.int64)
    gaps = np.diff(times) / 1e9
    rate = (len(times) - 1) / ((times[-1] - times[0]) / 1e9)
    print(f"{N_SUBS} subscriptions of {sub_bytes} bytes sent in {flood_s - 4.0:.1f} s: publisher RSS "
          f"{rss0:.1f} -> {rss1:.1f} MB; markers meanwhile {rate:.1f} Hz, longest gap {gaps.max() * 1e3:.0f} ms; publisher CPU {cpu:.2f} s")
    late = subscribe(manifest, ["markers"])
    assert late.poll(10000), "a new subscriber is served after the flood"
    if sub_bytes < 32:
        assert "[pattern] WARNING publisher: cut off subscriber ipc peer" in g.output
    assert rss1 - rss0 <= 20.0
    assert rate >= 0.8 * RATE_HZ
    assert gaps.max() <= 0.25, "the stream stalled while the publisher took the subscriptions"
    flood.close(0)
    late.close(0)
    observer.close(0)
    assert g.stop() == 0
