"""A launched graph for a benchmark: start `mocapgraph launch`, wait for a topic, stop it on the way out."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from mocapgraph.launch.manifest import NoGraphError, fetch_manifest


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
