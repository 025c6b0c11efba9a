"""Helpers shared by the tests that run real graphs: topic_logger files, waiting, processes."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

from mocapgraph.launch.manifest import fetch_manifest


def read_jsonl(path: Path, topic: str | None = None) -> list[dict]:
    """Records of a topic_logger file, optionally of one topic (a half-written last line is skipped)."""
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if topic is None or rec.get("topic") == topic:
            out.append(rec)
    return out


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
