"""The manifest of a running graph (nodes, topics, types, endpoints): typed builder, server, client.

The launcher serves it at the master endpoint ($MOCAPGRAPH_MASTER or a per-user ipc socket);
a standalone `bag play` serves its own; `topic echo`, `bag record` and friends fetch it. On the
wire it is one JSON object: {"graph", "launcher_pid", "nodes": [...], "topics": {topic: {"type",
"publishers": [{"node", "endpoint", "latched"}], "subscribers": [{"node", "port"}]}}}.
"""
from __future__ import annotations

import json
import os
import stat
import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable

import zmq

from ..messages.codec import topic_frame
from .user_dir import UnsafeDirError, user_dir, user_dir_path

REQUEST = b"manifest"


MAX_REQUEST_BYTES = 4096  # a manifest request is one short frame; a peer sending more is cut off
SERVE_BATCH = 64  # requests answered per call, so a flood cannot hold up the launcher's loop


def default_master() -> str:
    """Where the manifest is served: $MOCAPGRAPH_MASTER or a per-user ipc socket."""
    env = os.environ.get("MOCAPGRAPH_MASTER")
    if env:
        return env
    return f"ipc://{Path(tempfile.gettempdir()) / f'mocapgraph-{os.getuid()}' / 'master'}"


def check_master_dir(master: str, create: bool) -> None:
    """The directory of an ipc master must be safely ours (UnsafeDirError otherwise): the per-user
    default owned by us with mode 0700; any other one not owned by someone else and not open to
    writes by others (unless sticky, like /tmp)."""
    if not master.startswith("ipc://"):
        return
    parent = Path(master[6:]).parent
    if parent == user_dir_path():
        if create or parent.exists():
            user_dir(create=create)
        return
    if create:
        parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    try:
        st = os.stat(parent)
    except FileNotFoundError:
        return
    if st.st_uid not in (os.getuid(), 0):
        raise UnsafeDirError(f"{parent} belongs to uid {st.st_uid}, not to you: refusing to serve or trust a "
                             "manifest socket there")
    if stat.S_IMODE(st.st_mode) & 0o022 and not st.st_mode & stat.S_ISVTX:
        raise UnsafeDirError(f"{parent} is writable by others (mode {stat.S_IMODE(st.st_mode):04o}): refusing to "
                             "serve or trust a manifest socket there")


class NoGraphError(RuntimeError):
    """No launcher answers at the master endpoint."""


@dataclass
class NodeEntry:
    """One node process as the manifest lists it."""

    name: str
    type: str
    cls: str
    pid: int | None
    endpoint: str
    params: dict[str, Any]
    inputs: dict[str, str]
    outputs: dict[str, str]
    restarts: int = 0
    running: bool = True
    #: no diagnostics for STALL_S (launch/liveness.py): stopped or stuck
    stalled: bool = False
    #: outputs that stopped while the node's inputs kept receiving (launch/liveness.py)
    stalled_outputs: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["class"] = d.pop("cls")
        return d


@dataclass
class Manifest:
    """Nodes and topics of one running graph; ``to_dict`` gives the JSON form above."""

    graph: str
    launcher_pid: int = field(default_factory=os.getpid)
    nodes: list[NodeEntry] = field(default_factory=list)
    topics: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: {"key": .key_secret file, "authorized": folder} when the bus is CurveZMQ (paths, not keys:
    #: the manifest is served to this user only, and the tools read the files themselves)
    security: dict[str, str] = field(default_factory=dict)
    #: with --machine: the other machines' clocks as this launcher measures them (launch.machine_clock)
    clocks: dict[str, dict[str, Any]] = field(default_factory=dict)

    def _topic(self, topic: str, type_name: str) -> dict[str, Any]:
        return self.topics.setdefault(topic, {"type": type_name, "publishers": [], "subscribers": []})

    def add_publisher(self, topic: str, type_name: str, node: str, endpoint: str, latched: bool = False) -> None:
        self._topic(topic, type_name)["publishers"].append({"node": node, "endpoint": endpoint, "latched": latched})

    def add_subscriber(self, topic: str, type_name: str, node: str, port: str) -> None:
        self._topic(topic, type_name)["subscribers"].append({"node": node, "port": port})

    def to_dict(self) -> dict[str, Any]:
        return {"graph": self.graph, "launcher_pid": self.launcher_pid,
                "nodes": [n.to_dict() for n in self.nodes], "topics": self.topics, "security": self.security,
                "clocks": self.clocks}


def _answers(ctx: zmq.Context, endpoint: str, timeout_s: float) -> bytes | None:
    s = ctx.socket(zmq.REQ)
    s.setsockopt(zmq.LINGER, 0)
    try:
        s.connect(endpoint)
        s.send(REQUEST)
        return s.recv() if s.poll(int(timeout_s * 1000)) else None
    finally:
        s.close(0)


class ManifestServer:
    """Answers manifest requests at ``master``; refuses to take over one that still answers."""

    def __init__(self, master: str, ctx: zmq.Context | None = None) -> None:
        self.master = master
        ctx = ctx or zmq.Context.instance()
        try:
            check_master_dir(master, create=True)
        except UnsafeDirError as exc:
            raise ManifestBusyError(str(exc)) from None
        # ROUTER, not REP: a REP socket's state machine breaks on a malformed request (two parts, no
        # envelope) and the graph died with it; here each request is looked at and answered or dropped.
        self.socket = ctx.socket(zmq.ROUTER)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.MAXMSGSIZE, MAX_REQUEST_BYTES)
        self.socket.setsockopt(zmq.SNDHWM, 100)
        #: requests dropped as malformed since start
        self.malformed = 0
        if master.startswith("ipc://"):
            path = Path(master[6:])
            if path.exists() and _answers(ctx, master, 0.3) is not None:  # a stale socket file does not count
                self.socket.close(0)
                raise ManifestBusyError(f"another graph is already running at {master}; "
                                        "set MOCAPGRAPH_MASTER to run a second one")
        try:
            self.socket.bind(master)
        except zmq.ZMQError as exc:
            self.socket.close(0)
            raise ManifestBusyError(f"cannot serve the manifest at {master}: {exc}") from None

    def serve(self, build: Callable[[], Manifest]) -> None:
        """Answer waiting requests (non-blocking, at most SERVE_BATCH) with the manifest ``build()``
        gives now. A request is a REQ envelope around one frame; anything else is dropped and counted,
        an unknown one-frame request is answered with an error object."""
        reply: bytes | None = None
        for _ in range(SERVE_BATCH):
            try:
                frames = self.socket.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            if len(frames) != 3 or frames[1] != b"":
                self.malformed += 1
                continue
            if frames[2] == REQUEST:
                if reply is None:
                    reply = json.dumps(build().to_dict()).encode()
                body = reply
            else:
                self.malformed += 1
                body = json.dumps({"error": f"unknown request (send {REQUEST.decode()!r})"}).encode()
            try:
                self.socket.send_multipart([frames[0], b"", body], zmq.NOBLOCK)
            except zmq.ZMQError:
                pass  # the asker is gone or not reading: nothing to do

    def close(self) -> None:
        self.socket.close(0)
        if self.master.startswith("ipc://"):
            try:
                os.unlink(self.master[6:])
            except OSError:
                pass


class ManifestBusyError(RuntimeError):
    """The master endpoint is taken (another graph answers there, or it cannot be bound)."""


def fetch_manifest(master: str | None = None, timeout_s: float = 2.0) -> dict[str, Any]:
    """The running graph's manifest; NoGraphError when nothing answers in ``timeout_s``."""
    master = master or default_master()
    try:
        check_master_dir(master, create=False)  # a socket another user planted must not answer us
    except UnsafeDirError as exc:
        raise NoGraphError(str(exc)) from None
    reply = _answers(zmq.Context.instance(), master, timeout_s)
    if reply is None:
        raise NoGraphError(f"no running graph answers at {master} (start one with 'mocapgraph launch FILE', "
                           "or set MOCAPGRAPH_MASTER)")
    return json.loads(reply)


def topic_entry(manifest: dict[str, Any], topic: str) -> dict[str, Any]:
    """The manifest entry of ``topic``; KeyError with the known topics when absent."""
    try:
        return manifest["topics"][topic]
    except KeyError:
        known = ", ".join(sorted(manifest["topics"]))
        raise KeyError(f"no topic {topic!r} in the running graph (topics: {known})") from None


def subscribe(manifest: dict[str, Any], topics: list[str], hwm: int = 0) -> zmq.Socket:
    """A SUB socket connected to every publisher of ``topics`` (hwm 0: never drop)."""
    ctx = zmq.Context.instance()
    s = ctx.socket(zmq.SUB)
    s.setsockopt(zmq.RCVHWM, hwm)
    s.setsockopt(zmq.LINGER, 0)
    sec = manifest.get("security") or {}
    if sec.get("key"):
        from .curve import CurveKeys, make_client

        make_client(s, CurveKeys.load(sec["key"], sec["authorized"]))
    endpoints: set[str] = set()
    for t in topics:
        entry = topic_entry(manifest, t)
        endpoints.update(p["endpoint"] for p in entry["publishers"])
        s.setsockopt(zmq.SUBSCRIBE, topic_frame(t))
    for ep in sorted(endpoints):
        s.connect(ep)
    return s
