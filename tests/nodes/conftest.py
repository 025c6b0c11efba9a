"""Running one real reader node in its own process (``python -m mocapgraph.bus.runtime``, as the
launcher starts it, real ZeroMQ sockets) and collecting what it publishes, decoded, with
envelopes and receive stamps, and what it logs.

A process, not a thread of pytest: the node's native libraries (liblsl, ZeroMQ, numba) then share
nothing with the test process, and a node that misbehaves cannot crash the suite."""
from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import pytest
import zmq

from mocapgraph.bus import Wiring
from mocapgraph.bus.diagnostics import DIAGNOSTICS_TOPIC
from mocapgraph.bus.protocol import die_with_parent
from mocapgraph.launch.check import load_node_class
from mocapgraph.messages import decode
from mocapgraph.messages.codec import topic_frame


@dataclass
class Received:
    topic: str
    env: Any
    msg: Any
    receive_ns: int


@dataclass
class RunningNode:
    """A node running in a child process; ``got`` holds every message it published on watched
    topics (and its diagnostics), ``log_file`` what it logged."""

    proc: subprocess.Popen
    log_file: Path
    got: list[Received] = field(default_factory=list)
    _stop_rx: bool = False
    _rx: threading.Thread | None = None

    @property
    def exit_code(self) -> int | None:
        return self.proc.poll()

    def alive(self) -> bool:
        return self.proc.poll() is None

    def messages(self, topic: str) -> list[Any]:
        return [r.msg for r in list(self.got) if r.topic == topic]

    def records(self, topic: str) -> list[Received]:
        return [r for r in list(self.got) if r.topic == topic]

    def log(self) -> str:
        return self.log_file.read_text(errors="replace") if self.log_file.exists() else ""

    def logged(self, *texts: str, level: str | None = None) -> bool:
        """Whether one logged line holds every one of ``texts`` (at ``level``, e.g. "ERROR")."""
        return any(all(t in line for t in texts) and (level is None or line.startswith(level + " "))
                   for line in self.log().splitlines())

    def diagnostics(self, timeout: float = 10.0) -> Any:
        """The next Diagnostics message the node publishes (its counts as of now)."""
        seen = len(self.messages(DIAGNOSTICS_TOPIC))
        self.wait_for(lambda: len(self.messages(DIAGNOSTICS_TOPIC)) > seen, timeout, "diagnostics")
        return self.messages(DIAGNOSTICS_TOPIC)[-1]

    def wait_for(self, cond: Callable[[], Any], timeout: float = 10.0, what: str = "condition") -> Any:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            v = cond()
            if v:
                return v
            if not self.alive():
                time.sleep(0.05)  # what it sent last
                v = cond()
                if v:
                    return v
                raise AssertionError(f"node ended (exit {self.exit_code}) before {what}; it logged:\n{self.log()}")
            time.sleep(0.01)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}; the node logged:\n{self.log()}")

    def wait_exit(self, timeout: float = 10.0) -> int:
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"node did not stop; it logged:\n{self.log()}") from None
        # let the receiver drain what was sent last: until nothing new came for 0.2 s (a loaded
        # machine can hold the receiving thread back for longer than the node took to finish)
        t_end, n, quiet_since = time.monotonic() + 5.0, -1, time.monotonic()
        while time.monotonic() < t_end:
            if len(self.got) != n:
                n, quiet_since = len(self.got), time.monotonic()
            elif time.monotonic() - quiet_since > 0.2:
                break
            time.sleep(0.01)
        return code

    def stop(self) -> int | None:
        """SIGTERM (the node's on_stop runs, as under the launcher); SIGKILL after 10 s."""
        if self.alive():
            self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._stop_rx = True
        if self._rx is not None:
            self._rx.join(2)
        return self.exit_code


def _node_starter(folder: Path):
    """(start, started): a factory of RunningNodes whose files go in ``folder``, and the list it fills."""
    started: list[RunningNode] = []

    def start(type_name: str, params: dict[str, Any], topics: list[str] | None = None,
              name: str = "reader") -> RunningNode:
        class_path, cls = load_node_class(type_name)
        iface = cls.interface(params)
        outputs = {p: {"topic": o.topic, "subscribers": 1 if topics is None or o.topic in topics else 0}
                   for p, o in iface.outputs.items()}
        watched = [o["topic"] for o in outputs.values() if o["subscribers"]] + [DIAGNOSTICS_TOPIC]
        tag = uuid.uuid4().hex[:8]
        ep = f"ipc://{folder / ('n' + tag)}"
        wiring = Wiring(node=name, pub_endpoint=ep, outputs=outputs)
        wiring_file = folder / f"{name}-{tag}.json"
        wiring_file.write_text(json.dumps({"class": class_path, "params": params,
                                           "wiring": dataclasses.asdict(wiring)}))
        sub = zmq.Context.instance().socket(zmq.SUB)
        sub.setsockopt(zmq.RCVHWM, 0)
        sub.setsockopt(zmq.LINGER, 0)
        for t in watched:
            sub.setsockopt(zmq.SUBSCRIBE, topic_frame(t))
        sub.connect(ep)
        log_file = folder / f"{name}-{tag}.log"
        with open(log_file, "wb") as log:
            proc = subprocess.Popen([sys.executable, "-m", "mocapgraph.bus.runtime", str(wiring_file)],
                                    stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    cwd=os.getcwd(), preexec_fn=die_with_parent)
        rn = RunningNode(proc, log_file)

        def rx() -> None:
            while not rn._stop_rx:
                if sub.poll(20):
                    frames = sub.recv_multipart()
                    now = time.time_ns()
                    env, msg = decode(frames)
                    rn.got.append(Received(env.topic, env, msg, now))
            sub.close(0)

        rn._rx = threading.Thread(target=rx, daemon=True)
        rn._rx.start()
        started.append(rn)
        return rn

    return start, started


@pytest.fixture
def run_node(tmp_path: Path):
    """``run_node(type_name, params, topics=None)`` -> RunningNode (stopped at teardown)."""
    start, started = _node_starter(tmp_path)
    yield start
    for rn in started:
        rn.stop()


@pytest.fixture(scope="module")
def run_module_node(tmp_path_factory):
    """Like ``run_node``, for nodes a module's tests share (stopped after its last test): e.g. runs
    as fast as they go, started together so that each takes a core instead of queueing."""
    start, started = _node_starter(tmp_path_factory.mktemp("nodes"))
    yield start
    for rn in started:
        rn.stop()
