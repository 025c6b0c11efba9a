"""Helpers shared by the tests that run real graphs: topic_logger files, waiting, processes, commands."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any, Callable

from mocapgraph.bus.manifest import fetch_manifest


class _ParsedLog:
    """The complete lines of one JSON-lines file parsed so far (the file only grows: the logger
    appends), and where the parsing stopped."""

    def __init__(self, ident: tuple[int, int], head: bytes) -> None:
        self.ident, self.head = ident, head
        self.offset = 0
        self.records: list[dict] = []


_PARSED: dict[str, _ParsedLog] = {}   # path -> what was parsed of it, the few newest files only
_HEAD = 256                           # bytes that tell a file from another at the same path


def read_jsonl(path: Path, topic: str | None = None) -> list[dict]:
    """Records of a topic_logger file, optionally of one topic (a half-written last line is skipped).

    Tests poll growing logs many times a second while the graph runs on the same two cores, and a
    log of a whole capture is megabytes: each call parses only the lines appended since the last
    (the same records as parsing the whole file; a file replaced or cut short is parsed again)."""
    path = Path(path)
    try:
        f = open(path, "rb")
    except FileNotFoundError:
        _PARSED.pop(str(path), None)
        return []
    with f:
        st = os.fstat(f.fileno())
        head = f.read(_HEAD)
        log = _PARSED.get(str(path))
        if (log is None or log.ident != (st.st_dev, st.st_ino) or st.st_size < log.offset
                or head[:len(log.head)] != log.head):
            log = _ParsedLog((st.st_dev, st.st_ino), head)
        f.seek(log.offset)
        new = f.read()
    end = new.rfind(b"\n") + 1                # whole lines only: the last may be half-written
    for line in new[:end].decode(errors="replace").splitlines():
        try:
            log.records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    log.offset += end
    if len(log.head) < _HEAD:
        log.head = head
    _PARSED.pop(str(path), None)
    _PARSED[str(path)] = log
    while len(_PARSED) > 8:
        del _PARSED[next(iter(_PARSED))]
    recs = log.records
    try:                                       # a last line complete but for its newline counts too
        tail = [json.loads(new[end:])] if new[end:].strip() else []
    except (json.JSONDecodeError, UnicodeDecodeError):
        tail = []
    return [r for r in (recs + tail) if topic is None or r.get("topic") == topic]


def wait_until(cond: Callable[[], Any], timeout: float = 15.0, what: str = "condition", graph=None) -> Any:
    """Poll ``cond`` until it returns something truthy (returned); AssertionError on time-out,
    with the graph's output when one is given."""
    t_end = time.monotonic() + timeout
    last = None
    while time.monotonic() < t_end:
        last = cond()
        if last:
            return last
        time.sleep(0.05)
    raise AssertionError(f"timed out after {timeout} s waiting for {what} (last: {last!r})"
                         + (f"; output:\n{graph.output}" if graph is not None else ""))


def pid_alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie counts as dead)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def node_pids(graph) -> dict[str, int]:
    """Node name -> pid of a launched graph, from its manifest."""
    return {n["name"]: n["pid"] for n in fetch_manifest(graph.master)["nodes"]}


def assert_pattern_frame(rec: dict, n_markers: int, rate_hz: float, missing_every: int) -> None:
    """A topic_logger record of a marker_test_pattern frame carries exactly the pattern's positions,
    marker 0 NaN and invalid on every ``missing_every``-th frame."""
    import numpy as np
    from mocapgraph.testing.marker_pattern import pattern_positions

    assert rec["type"] == "MarkerFrame" and rec["sender"] == "pattern", rec
    frame = rec["msg"]["frame_number"]
    pos = np.array(rec["msg"]["positions"], dtype=float)
    want = pattern_positions(frame, n_markers, rate_hz)
    if frame % missing_every == 0:
        assert np.isnan(pos[0]).all() and rec["msg"]["valid"][0] is False
        pos, want = pos[1:], want[1:]
    np.testing.assert_array_equal(pos, want)


class CommandsRunning:
    """Independent commands started at once (stdout and stderr captured as text); ``results()``
    waits for them. Each `python -m mocapgraph` spends ~1 s of CPU importing before it does
    anything, so a test's independent CLI calls share both cores instead of queueing, or run
    while the test waits for something else."""

    def __init__(self, commands: list[list[str]], **popen_kw) -> None:
        import subprocess

        self.commands = commands
        self.procs = [subprocess.Popen(c, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                       text=True, **popen_kw) for c in commands]

    def results(self, timeout: float = 60.0) -> list:
        """Their CompletedProcesses in the given order (like subprocess.run(..., capture_output=True,
        text=True)); the time-out is a deadline against hangs, for all of them together."""
        import subprocess

        t_end = time.monotonic() + timeout
        out = []
        try:
            for c, p in zip(self.commands, self.procs):
                stdout, stderr = p.communicate(timeout=max(0.1, t_end - time.monotonic()))
                out.append(subprocess.CompletedProcess(c, p.returncode, stdout, stderr))
        finally:
            for p in self.procs:
                if p.poll() is None:
                    p.kill()
                    p.wait()
        return out


def run_concurrently(commands: list[list[str]], timeout: float = 60.0, **popen_kw) -> list:
    """Run independent commands at once -> their CompletedProcesses in order (see CommandsRunning)."""
    return CommandsRunning(commands, **popen_kw).results(timeout)


def graph_error(path: Path, text: str) -> str:
    """The one-line error `graph check` gives for the graph ``text`` written to ``path``."""
    import pytest

    from mocapgraph.formats.yaml_source import GraphError
    from mocapgraph.launch.check import check_graph
    from mocapgraph.launch.graph import load_graph
    path.write_text(text)
    with pytest.raises(GraphError) as exc:
        check_graph(load_graph(path))
    return str(exc.value)


class CommandSender:
    """An external publisher of NodeCommand on ``topic`` (declared under ``external:`` in the
    graph at ``tcp://127.0.0.1:<port>``), as a control panel or script would send them."""

    def __init__(self, topic: str, node: str = "the node") -> None:
        import zmq

        self.topic, self.node = topic, node
        self.sock = zmq.Context.instance().socket(zmq.XPUB)
        self.port = self.sock.bind_to_random_port("tcp://127.0.0.1")
        self.seq = 0

    @property
    def external(self) -> str:
        """The graph's ``external:`` block declaring this publisher."""
        return (f"external:\n  - {{topic: {self.topic}, type: NodeCommand, "
                f"endpoint: \"tcp://127.0.0.1:{self.port}\"}}\n")

    def wait_subscriber(self, timeout_s: float = 30.0) -> None:
        from mocapgraph.messages.codec import topic_frame

        assert self.sock.poll(int(timeout_s * 1000)), f"{self.node} never subscribed to {self.topic}"
        assert self.sock.recv() == b"\x01" + topic_frame(self.topic)

    def send(self, command: str, target: str = "", **args: Any) -> None:
        from mocapgraph.messages import NodeCommand, encode

        self.seq += 1
        msg = NodeCommand(target=target, command=command, args_json=json.dumps(args))
        self.sock.send_multipart([bytes(f) for f in encode(self.topic, msg, self.seq, time.time_ns(), "test")])

    def close(self) -> None:
        self.sock.close(0)
