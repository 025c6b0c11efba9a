"""A launched graph for a benchmark: start `mocapgraph launch`, wait for a topic, stop it on the way out; pair two topics' publish stamps."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from mocapgraph.bus.manifest import NoGraphError, fetch_manifest


@contextmanager
def launched_graph(graph_yaml: str, wait_topic: str, tmp: Path, timeout_s: float = 60.0) -> Iterator[dict[str, Any]]:
    """Launch ``graph_yaml`` (written to ``tmp``) on its own master; yield its manifest once
    ``wait_topic`` is published; SIGINT the whole launch on exit (SIGKILL if it lingers)."""
    graph = tmp / "graph.yaml"
    graph.write_text(graph_yaml)
    master = f"ipc://{tmp}/master"
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph", "launch", str(graph)], cwd=tmp,   # (its logs land there)
                            env=dict(os.environ, MOCAPGRAPH_MASTER=master), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        t_end = time.monotonic() + timeout_s
        while True:
            try:
                manifest = fetch_manifest(master, 0.5)
                if wait_topic in manifest["topics"]:
                    break
            except NoGraphError:
                pass
            if time.monotonic() > t_end:
                raise SystemExit("graph did not start")
        yield manifest
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def paired_latencies_ms(sock, first_topic: str, seconds: float, warm_s: float, timeout_s: float = 180.0) -> list[float]:
    """Publish stamp of the other topic minus ``first_topic``'s, ms, for each capture stamp seen on
    both (a node publishes its frame with its input's capture stamp) on the SUB ``sock``: from
    ``warm_s`` after the first pair for ``seconds`` (nothing after ``timeout_s`` without one)."""
    from mocapgraph.messages import decode_envelope
    first: dict[int, int] = {}
    other: dict[int, int] = {}
    out: list[float] = []
    t_end = time.monotonic() + timeout_s
    t_warm = None
    while time.monotonic() < t_end:
        if not sock.poll(200):
            continue
        env = decode_envelope(sock.recv_multipart())
        (first if env.topic == first_topic else other)[env.capture_ns] = env.publish_ns
        k = env.capture_ns
        if k in first and k in other:
            a, b = first.pop(k), other.pop(k)
            now = time.monotonic()
            if t_warm is None:   # the first pair: start-up (calibration, kernels) is over
                t_warm = now + warm_s
                t_end = t_warm + seconds
            elif now > t_warm:
                out.append((b - a) * 1e-6)
    return out


def launched_latencies_ms(graph_yaml: str, first_topic: str, second_topic: str, seconds: float, warm_s: float,
                          start_timeout_s: float = 60.0) -> list[float]:
    """Launch ``graph_yaml`` and return :func:`paired_latencies_ms` of its two topics (``second_topic``'s
    publish stamp minus ``first_topic``'s, ms)."""
    import tempfile
    from mocapgraph.bus.manifest import subscribe
    with tempfile.TemporaryDirectory() as tmp, launched_graph(graph_yaml, second_topic, Path(tmp),
                                                             start_timeout_s) as manifest:
        sock = subscribe(manifest, [first_topic, second_topic])
        try:
            return paired_latencies_ms(sock, first_topic, seconds, warm_s)
        finally:
            sock.close(0)


def reader_process(tmp: Path, type_path: str, params: dict[str, Any], topic: str = "markers"):
    """A reader node in its own process, as the launcher starts one (``python -m
    mocapgraph.bus.runtime WIRING.json``), and a SUB socket of this process on its output ``topic``;
    its stderr is kept (a pipe, text) for the caller's error line. Returns (process, socket)."""
    import json

    import zmq

    from mocapgraph.messages.codec import topic_frame

    ep = f"ipc://{tmp / ('reader-' + str(time.monotonic_ns()))}"
    spec = {"class": type_path, "params": params,
            "wiring": {"node": "reader", "pub_endpoint": ep,
                       "outputs": {topic: {"topic": topic, "subscribers": 1}}}}
    wf = tmp / f"wiring-{time.monotonic_ns()}.json"
    wf.write_text(json.dumps(spec))
    sub = zmq.Context.instance().socket(zmq.SUB)
    sub.setsockopt(zmq.RCVHWM, 0)
    sub.setsockopt(zmq.SUBSCRIBE, topic_frame(topic))
    sub.connect(ep)
    proc = subprocess.Popen([sys.executable, "-m", "mocapgraph.bus.runtime", str(wf)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    return proc, sub


def stop_reader(proc: subprocess.Popen, sub) -> None:
    """SIGTERM the reader (a kill after 5 s) and close the socket."""
    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(5)
    except subprocess.TimeoutExpired:
        proc.kill()
    sub.close(0)
