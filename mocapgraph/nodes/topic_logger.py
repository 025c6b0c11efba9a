"""Writes every message of the topics it watches as one JSON line each (debugging, tests)."""
from __future__ import annotations

import json
import time
from typing import Any

from ..bus import Input, Interface, Node, Param
from ..bus.file_places import PathRefused, own_folder_path
from ..bus.node import NodeConfigError
from ..messages import Message


class TopicLogger(Node):
    """Appends each received message (envelope + fields) to a JSON-lines file, flushed per line."""

    summary = "log messages of chosen topics to a JSON-lines file"
    path = Param("topics.jsonl", "output file (appended)")
    topics = Param(["markers"], "topics to log (any message type)")
    flush_every = Param(1, "flush after this many lines", minimum=1)

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        for i, topic in enumerate(params.get("topics", cls.topics.default)):
            iface.inputs[f"in{i}"] = Input(str(topic), None, f"logged topic {topic}", name=f"in{i}")
        return iface

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        try:  # a regular file where the graph says: never a device, a fifo or a symlink elsewhere
            self._file = open(own_folder_path(self.path, "parameter 'path'"), "a", buffering=1 << 16)
        except PathRefused as exc:
            raise NodeConfigError(str(exc)) from None
        except OSError as exc:
            raise NodeConfigError(f"parameter 'path': cannot open {self.path}: {exc.strerror or exc}") from None
        self._lines = 0

    def input_handler(self, port_name: str):
        port = self.input_ports[port_name]

        def write(msg: Message) -> None:
            env = port.envelope
            rec = {"topic": env.topic, "type": env.type_name, "seq": env.seq, "sender": env.sender,
                   "capture_ns": env.capture_ns, "publish_ns": env.publish_ns, "receive_ns": time.time_ns(),
                   "msg": msg.to_dict()}
            self._file.write(json.dumps(rec, allow_nan=True) + "\n")
            self._lines += 1
            if self._lines % self.flush_every == 0:
                self._file.flush()

        return write

    def on_stop(self) -> None:
        self._file.close()
