"""The launcher protocol: the wiring a node is handed, the control messages, the parent watchdog.

A node started by the launcher connects a DEALER socket (identity = node name) to the
launcher's ROUTER at ``Wiring.control`` and speaks these one-frame messages:

    node -> launcher: HELLO pid, READY (every expected subscriber is connected), STARTED, BYE
    launcher -> node: START (run on_start, sources begin publishing), STOP,
                      CLOCKS + JSON (the other machines' clocks: launch.machine_clock)

Both sides import the constants from here, so the protocol is written once.
"""
from __future__ import annotations

import ctypes
import os
import signal
from dataclasses import dataclass, field
from typing import Any

import zmq

HELLO = b"hello"
READY = b"ready"
STARTED = b"started"
BYE = b"bye"
START = b"start"
STOP = b"stop"
CLOCKS = b"clocks"

PR_SET_PDEATHSIG = 1


@dataclass
class Wiring:
    """How the launcher connects one node: its endpoint, its topics and their publishers.

    inputs: input name -> {"topic": str, "endpoints": [publisher endpoints]}
    outputs: output name -> {"topic": str, "subscribers": expected subscriber count}
    control: the launcher's control endpoint ("" when the node runs by itself)
    curve: key file and authorised-keys folder when the graph has a security: section
    """

    node: str
    pub_endpoint: str = ""
    inputs: dict[str, dict[str, Any]] = field(default_factory=dict)
    outputs: dict[str, dict[str, Any]] = field(default_factory=dict)
    control: str = ""
    diagnostics_subscribers: int = 0
    #: CurveZMQ on every bus socket: {"key": .key_secret file, "authorized": folder}; empty: plaintext
    curve: dict[str, str] = field(default_factory=dict)


def die_with_parent() -> None:
    """Linux: SIGTERM this process when its parent exits (preexec hook of the launcher)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:
        pass  # not Linux: ParentWatchdog is the fallback


class ParentWatchdog:
    """Notices that the process that started us is gone (its pid is no longer our parent)."""

    def __init__(self) -> None:
        self._parent_pid = os.getppid()

    def parent_gone(self) -> bool:
        return os.getppid() != self._parent_pid


class LauncherLink:
    """A node's end of the control channel: say HELLO on connect, send and receive commands."""

    def __init__(self, ctx: zmq.Context, endpoint: str, node_name: str) -> None:
        self.socket = ctx.socket(zmq.DEALER)
        self.socket.setsockopt(zmq.IDENTITY, node_name.encode())
        self.socket.setsockopt(zmq.LINGER, 200)
        self.socket.connect(endpoint)
        self.socket.send_multipart([HELLO, str(os.getpid()).encode()])

    def send(self, command: bytes) -> None:
        self.socket.send_multipart([command])

    def received(self) -> list[bytes]:
        """Every command waiting now (first frame of each message)."""
        out = []
        while True:
            try:
                out.append(self.socket.recv_multipart(zmq.NOBLOCK)[0])
            except zmq.Again:
                return out

    def close(self) -> None:
        try:
            self.socket.send_multipart([BYE], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass
        self.socket.close()
