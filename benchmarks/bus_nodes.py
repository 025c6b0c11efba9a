"""Nodes used only by benchmarks/bus.py (graph type: benchmarks/bus_nodes.py:Class, named by file)."""
from __future__ import annotations

import time

import numpy as np

from mocapgraph.bus import Input, Node, Output, Param
from mocapgraph.messages import MarkerFrame


def frame(n: int, i: int) -> MarkerFrame:
    pos = np.random.default_rng(i).normal(size=(n, 3))
    return MarkerFrame(frame_number=i, rate_hz=240.0, positions=pos, valid=np.ones(n, bool),
                       residual=np.zeros(n, np.float32))


class BenchSender(Node):
    """Sends MarkerFrames: paced by a timer (rate_hz > 0) or ping-pong (rate_hz == 0)."""

    out = Output("ping", MarkerFrame)
    back = Input("pong", MarkerFrame, required=False)
    rate_hz = Param(240.0, "send rate; 0 = next frame when the previous came back")
    count = Param(2000, "frames to send")
    burst = Param(False, "send count frames in one tight loop")
    n_markers = Param(64, "markers per frame")
    out_file = Param("", "where to write the number of frames actually sent, on stop")

    def on_start(self) -> None:
        self.sent = 0
        self.msg = frame(self.n_markers, 0)
        if self.burst:
            self._burst_timer = self.add_timer(0.2, self._burst)
        elif self.rate_hz > 0:
            self.add_timer(1.0 / self.rate_hz, self._send, first_delay_s=0.2)
        else:
            self.add_timer(0.2, self._kick)

    def _send(self) -> None:
        if self.sent >= self.count:
            return
        self.sent += 1
        self.msg.frame_number = self.sent
        self.out.publish(self.msg)

    def _kick(self) -> None:
        if self.sent == 0:
            self._send()

    def _burst(self) -> None:
        self._burst_timer.cancel()
        for _ in range(self.count - 1):
            self._send()
        # The last one once the queues drained: every loss before it shows as a sequence gap.
        self._last_timer = self.add_timer(1.0, self._last, first_delay_s=0.3)

    def _last(self) -> None:
        self._last_timer.cancel()
        self._send()

    def on_back(self, msg: MarkerFrame) -> None:
        time.sleep(0.0002)  # let the receiver settle, so each sample is an idle-path latency
        self._send()

    def on_stop(self) -> None:
        if self.out_file:   # what was really sent: a slow sender is not a lossy bus
            with open(self.out_file, "w") as f:
                f.write(f"{self.sent}\n")


class BenchReceiver(Node):
    """Records one-way latency (receive - publish stamp) and optionally echoes back."""

    inp = Input("ping", MarkerFrame, queue=1000)
    back = Output("pong", MarkerFrame)
    echo = Param(False, "publish every frame back on pong")
    out_file = Param("", "where to save latencies (ns, .npy) and counts on stop")
    queue = Param(1000, "receive queue depth (messages)")

    @classmethod
    def interface(cls, params):
        iface = super().interface(params)
        iface.inputs["inp"] = Input("ping", MarkerFrame, queue=int(params.get("queue", 1000)), name="inp")
        return iface

    def on_start(self) -> None:
        pass

    def input_handler(self, name):
        self.lat: list[int] = []
        self.port = self.input_ports[name]
        return self._on_inp

    def _on_inp(self, msg: MarkerFrame) -> None:
        self.lat.append(time.time_ns() - self.port.envelope.publish_ns)
        if self.echo:
            self.back.publish(msg)

    def on_stop(self) -> None:
        if self.out_file:
            edges = list(self.port.stats.edges.values())
            gaps = sum(e.gaps for e in edges)
            last = max((e.last_seq for e in edges), default=0)
            np.save(self.out_file, np.array(self.lat, np.int64))
            with open(self.out_file + ".counts", "w") as f:
                f.write(f"{len(self.lat)} {gaps} {last}\n")
