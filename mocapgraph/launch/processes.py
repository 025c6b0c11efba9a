"""The graph's OS processes and their supervision state: which nodes each runs, respawn and back-off.

A process runs one node, or the nodes of a ``process:`` group (`launch.check.process_groups`);
the supervisor starts, watches and stops processes, and speaks the control protocol with nodes.
"""
from __future__ import annotations

import os
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path

from ..bus.protocol import Wiring, die_with_parent
from .check import ResolvedNode

MAX_BACKOFF_S = 10.0


@dataclass
class Process:
    """One OS process of the graph (a node, or the nodes of a ``process:`` group) and its supervision state."""

    name: str
    members: list["Child"] = field(default_factory=list)
    proc: subprocess.Popen | None = None
    restarts: int = 0
    backoff_s: float = 0.5
    respawn_at: float | None = None
    started_at: float = 0.0
    finished: bool = False
    threads: list[threading.Thread] = field(default_factory=list)

    @property
    def respawn(self) -> bool:
        return self.members[0].node.spec.respawn  # the same for every member (graph check)

    @property
    def respawn_delay(self) -> float:
        return self.members[0].node.spec.respawn_delay

    @property
    def respawn_max_delay(self) -> float:
        return self.members[0].node.spec.respawn_max_delay

    @property
    def nice(self) -> int:
        return self.members[0].node.spec.nice  # the same for every member (graph check)

    def before_exec(self) -> None:
        """In the child, before the runtime starts: die with the launcher, take the niceness."""
        die_with_parent()
        if self.nice:
            os.nice(self.nice)

    @property
    def required(self) -> bool:
        return any(c.node.spec.required for c in self.members)

    @property
    def solo(self) -> bool:
        """A node in a process of its own (no ``process:``)."""
        return len(self.members) == 1 and not self.members[0].node.spec.process

    @property
    def label(self) -> str:
        """How the launcher's lines name it: the node, or the process and its nodes."""
        if self.solo:
            return f"node {self.members[0].node.name}"
        return f"process {self.name} ({', '.join(c.node.name for c in self.members)})"

    def respawn_due(self, now: float) -> bool:
        """True (once) when it has exited and its respawn back-off is over: spawn it again now."""
        if (self.finished or self.proc is None) and self.respawn_at is not None and now >= self.respawn_at:
            self.respawn_at = None
            self.finished = False
            self.restarts += 1
            return True
        return False

    def poll_exit(self, now: float, stopping: bool) -> int | None:
        """Its exit code when it has just exited (a respawn scheduled if it respawns and the graph is
        not stopping); None while it runs, and once its exit was reported."""
        if self.finished or self.proc is None:
            return None
        code = self.proc.poll()
        if code is None:
            if now - self.started_at > MAX_BACKOFF_S:
                self.backoff_s = self.respawn_delay  # healthy for a while: reset back-off
            return None
        self.finished = True
        if self.respawn and not stopping:
            self.respawn_at = now + self.backoff_s
            self.backoff_s = min(self.respawn_max_delay, self.backoff_s * 2)
        return code


@dataclass
class Child:
    """One node of the graph: its wiring, its handshake state, the process it runs in."""

    node: ResolvedNode
    wiring: Wiring
    wiring_file: Path
    process: Process | None = None
    ready: bool = False
    started: bool = False
    stopped: bool = False  # said BYE (left its loop; its process may serve others still)

    @property
    def proc(self) -> subprocess.Popen | None:
        return self.process.proc if self.process is not None else None

    @property
    def restarts(self) -> int:
        return self.process.restarts if self.process is not None else 0


def group_processes(children: dict[str, Child], groups: dict[str, list[str]]) -> dict[str, Process]:
    """The processes this launcher runs, from the graph's groups (key -> node names) and its own
    nodes (``children``: with --machine, the nodes of that machine only); each child learns its process."""
    out: dict[str, Process] = {}
    for key, names in groups.items():
        members = [children[n] for n in names if n in children]
        if not members:
            continue
        p = out[key] = Process(key.removeprefix("process:"), members, backoff_s=members[0].node.spec.respawn_delay)
        for c in members:
            c.process = p
    return out
