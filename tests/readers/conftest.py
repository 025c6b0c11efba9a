"""Running one real reader node in this process (its own thread, real ZeroMQ sockets) and
collecting what it publishes, decoded, with envelopes and receive stamps."""
from __future__ import annotations

import threading
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import pytest
import zmq

from mocapgraph.bus import Wiring
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
    """A node running in a thread; ``got`` holds every message it published on watched topics."""

    node: Any
    thread: threading.Thread
    got: list[Received] = field(default_factory=list)
    exit_code: int | None = None
    _stop_rx: bool = False
    _rx: threading.Thread | None = None

    def messages(self, topic: str) -> list[Any]:
        return [r.msg for r in list(self.got) if r.topic == topic]

    def records(self, topic: str) -> list[Received]:
        return [r for r in list(self.got) if r.topic == topic]

    def wait_for(self, cond: Callable[[], Any], timeout: float = 10.0, what: str = "condition") -> Any:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            v = cond()
            if v:
                return v
            if not self.thread.is_alive() and not cond():
                raise AssertionError(f"node ended (exit {self.exit_code}) before {what}")
            time.sleep(0.01)
        raise AssertionError(f"timed out after {timeout} s waiting for {what}")

    def wait_exit(self, timeout: float = 10.0) -> int:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "node did not stop"
        time.sleep(0.05)  # let the receiver drain what was sent last
        return self.exit_code

    def stop(self) -> int | None:
        self.node.request_stop()
        self.thread.join(5)
        self._stop_rx = True
        if self._rx is not None:
            self._rx.join(2)
        return self.exit_code


@pytest.fixture
def run_node(tmp_path: Path):
    """``run_node(type_name, params, topics=None)`` -> RunningNode (stopped at teardown)."""
    started: list[RunningNode] = []

    def start(type_name: str, params: dict[str, Any], topics: list[str] | None = None,
              name: str = "reader") -> RunningNode:
        _, cls = load_node_class(type_name)
        iface = cls.interface(params)
        outputs = {p: {"topic": o.topic, "subscribers": 1 if topics is None or o.topic in topics else 0}
                   for p, o in iface.outputs.items()}
        watched = [o["topic"] for o in outputs.values() if o["subscribers"]]
        ep = f"ipc://{tmp_path / ('n' + uuid.uuid4().hex[:8])}"
        node = cls(name, params, Wiring(node=name, pub_endpoint=ep, outputs=outputs))
        ctx = zmq.Context.instance()
        sub = ctx.socket(zmq.SUB)
        sub.setsockopt(zmq.RCVHWM, 0)
        sub.setsockopt(zmq.LINGER, 0)
        for t in watched:
            sub.setsockopt(zmq.SUBSCRIBE, topic_frame(t))
        sub.connect(ep)
        rn = RunningNode(node, None)  # type: ignore[arg-type]

        def body() -> None:
            rn.exit_code = node.run()

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
        rn.thread = threading.Thread(target=body, daemon=True)
        rn.thread.start()
        started.append(rn)
        return rn

    yield start
    for rn in started:
        rn.stop()
