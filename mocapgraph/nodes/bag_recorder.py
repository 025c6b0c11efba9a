"""Records chosen topics of the graph into an MCAP bag (see mocapgraph.bag)."""
from __future__ import annotations

import json
from datetime import datetime
from typing import Any

from ..bag.errors import BagError
from ..bag.recorder import FLUSH_PERIOD_S, Recorder
from ..bag.writer import COMPRESSIONS, BagWriter, base_metadata
from ..bus import Input, Interface, Node, Param
from ..bus.node import NodeConfigError


def default_bag_name() -> str:
    return datetime.now().strftime("mocapgraph_%Y%m%d_%H%M%S.mcap")


class BagRecorder(Node):
    """Stores every message of its topics, byte for byte, with capture and publish stamps.

    Subscribes without a high-water mark (never drops on its side), counts messages lost upstream
    from sequence numbers and writes the counts into the bag; closes a chunk every ``flush_s`` so
    that a recorder killed with SIGKILL loses at most about that much (``bag recover``).
    """

    summary = "record topics into an MCAP bag (crash-safe chunks, losses counted)"
    path = Param("", "output .mcap file ('' names it mocapgraph_<date>_<time>.mcap in the working folder)")
    topics = Param(["markers"], "topics to record (any type)")
    compression = Param("lz4", "chunk compression", choices=tuple(COMPRESSIONS))
    chunk_kb = Param(256, "chunk size that closes a chunk early, KiB", minimum=16)
    flush_s = Param(FLUSH_PERIOD_S, "close and flush the open chunk this often, s", minimum=0.01)
    split_mb = Param(0.0, "start a new file after this many MB (0: never)", minimum=0.0)
    split_s = Param(0.0, "start a new file after this many seconds (0: never)", minimum=0.0)

    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        iface = super().interface(params)
        topics = params.get("topics", cls.topics.default)
        if isinstance(topics, list):
            for i, topic in enumerate(topics):
                iface.inputs[f"in{i}"] = Input(str(topic), None, f"recorded topic {topic}", queue=0, raw=True,
                                               name=f"in{i}")
        return iface

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring=None) -> None:
        super().__init__(name, params, wiring)
        if not self.topics:
            raise NodeConfigError("parameter 'topics' is empty: name at least one topic to record")
        self.recorder: Recorder | None = None
        self._failed = False

    def _open(self) -> Recorder:
        if self.recorder is None:
            meta = base_metadata("bag_recorder node", node=self.name, params_json=json.dumps(self.params))
            meta.update(_graph_metadata())
            path = self.path or default_bag_name()
            try:
                writer = BagWriter(path, compression=self.compression, chunk_kb=self.chunk_kb,
                                   split_mb=self.split_mb, split_s=self.split_s, metadata=meta, on_exists="rename")
            except BagError as exc:
                raise NodeConfigError(str(exc)) from None
            self.recorder = Recorder(writer, self.flush_s)
            self.log.info("recording %s to %s", ", ".join(self.topics), writer.paths[0])
        return self.recorder

    def on_start(self) -> None:
        self._open()
        self.add_timer(min(0.05, self.flush_s), self._tick)

    def _tick(self) -> None:
        if self.recorder is not None and not self.recorder.writer.failed:
            try:
                self.recorder.tick()
            except (OSError, BagError) as exc:
                self._cannot(exc)

    def _cannot(self, exc: Exception) -> None:
        """Disk full, folder gone: one line, stop (the writer keeps what reached the disk, and
        removes a file that got nothing, so a respawn loop leaves no empty bags)."""
        if not self._failed:
            self._failed = True
            self.exit_code = 1   # a recorder that cannot record has failed (a required one stops the graph)
            self.log.error("cannot record: %s", exc)
            self.request_stop()

    def input_handler(self, port_name: str):
        return self._record

    def _record(self, env, frames) -> None:  # noqa: ANN001 - raw input handler
        # Raw frames straight into the bag: no payload decode, unknown types kept as they came.
        if self._failed:
            return
        try:
            self._open().receive(frames, env)
        except (OSError, BagError, NodeConfigError) as exc:  # disk full, folder gone: say so and stop
            self._cannot(exc)

    def on_stop(self) -> None:
        if self.recorder is not None:
            try:
                paths = self.recorder.close()
            except BagError as exc:
                if not self._failed:   # (already said in one line)
                    self.log.error("cannot record: %s", exc)
                return
            self.log.info("recorded %s to %s", self.recorder.status(), ", ".join(map(str, paths)))


def _graph_metadata() -> dict[str, str]:
    """Graph file and every node's params from the launcher's manifest, when one answers."""
    try:
        from ..bus.manifest import fetch_manifest

        m = fetch_manifest(timeout_s=0.5)
    except Exception:  # noqa: BLE001 - metadata is best effort; recording must go on
        return {}
    return {"graph": str(m.get("graph", "")),
            "nodes_json": json.dumps([{k: n.get(k) for k in ("name", "type", "params")} for n in m.get("nodes", [])])}
