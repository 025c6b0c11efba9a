"""Running a checked graph: one OS process per node (or per ``process:`` group), readiness handshake,
logs, respawn, shutdown.

- Every node is started as ``python -m mocapgraph.bus.runtime WIRING.json`` in its own session,
  with the kernel told to SIGTERM it when the launcher dies (no orphans even after SIGKILL); the
  nodes of a ``process:`` group share one such process (``runtime A.json B.json``), which is
  watched, respawned and stopped as one.
- Nodes say ``ready`` on the control socket once every subscriber the graph expects has
  subscribed to their outputs; only then does the launcher send ``start`` to all, so sources
  never publish into the void (ZeroMQ's slow-joiner loss).
- Each node's output lines are prefixed with ``[name]``.
- A node that dies is respawned with doubling back-off when asked; a required node that dies
  stops the graph (exit code 1).
- Shutdown goes upstream first (sources, then processing, then recorders) so that downstream
  nodes drain what was sent.
- The launcher answers manifest requests (nodes, topics, types, endpoints) on the master
  endpoint, for tools started later (``mocapgraph topic echo``, ``bag record``).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import IO, Any

import zmq

from ..bus.diagnostics import DIAGNOSTICS_TOPIC
from ..bus.protocol import BYE, CLOCKS, READY, START, STARTED, STOP
from .check import CheckedGraph, ResolvedNode, process_groups, shutdown_order
from ..bus.curve import CurveKeys
from .liveness import STALL_S, Liveness, OutputWatch, diagnostics_socket, drain_diagnostics, heard_lines
from .processes import Child, Process, group_processes
from ..bus.manifest import Manifest, ManifestBusyError, ManifestServer, NodeEntry, default_master  # noqa: F401
from .machine_clock import MachineClocks, machine_addresses
from .wiring_plan import plan_wiring

READY_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 2.0
START_ACK_TIMEOUT_S = 5.0


def _free_tcp_port(host: str) -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def _endpoint(rn: ResolvedNode, run_dir: Path) -> str:
    """Where ``rn`` binds its publisher: its tcp host and port, a free port, or an ipc socket in ``run_dir``."""
    host = rn.spec.host
    if host and rn.spec.port:
        return f"tcp://{host}:{rn.spec.port}"
    if host and host not in ("localhost",):
        return f"tcp://{host}:{_free_tcp_port(host)}"
    return f"ipc://{run_dir / (rn.name + '.pub')}"


class LaunchError(RuntimeError):
    """The graph could not be brought up (a node failed to start or become ready)."""


class Supervisor:
    """Starts, watches and stops the processes of a checked graph."""

    def __init__(self, graph: CheckedGraph, master: str | None = None, out: IO[str] | None = None,
                 machine: str | None = None) -> None:
        self.machine = machine
        self.graph = graph
        self.master = master or default_master()
        self.out = out or sys.stdout
        self._out_lock = threading.Lock()
        self.run_dir = Path(tempfile.mkdtemp(prefix=f"mocapgraph-{os.getpid()}-"))
        self.liveness = Liveness()
        self.outputs = OutputWatch.of_graph(graph)
        self.diag: zmq.Socket | None = None
        self.ctx = zmq.Context.instance()
        self.control_ep = f"ipc://{self.run_dir / 'control'}"
        self.children: dict[str, Child] = {}
        self.processes: dict[str, Process] = {}
        self._stop_requested = False
        self._exit_code = 0
        self.clocks: MachineClocks | None = None
        self._clocks_told = 0.0
        self._clocks_said: dict[str, float] = {}
        self._plan()

    # ----- planning -----------------------------------------------------------------------
    def local(self, rn: ResolvedNode) -> bool:
        """Whether this launcher runs ``rn`` (with --machine: the nodes of that machine only)."""
        return self.machine is None or rn.spec.machine == self.machine

    def _plan(self) -> None:
        self.endpoints = {rn.name: _endpoint(rn, self.run_dir) for rn in self.graph.nodes}
        plan = plan_wiring(self.graph, self.endpoints, self.control_ep)
        for rn in self.graph.nodes:
            if not self.local(rn):
                continue  # runs on another machine; its endpoint is in the plan all the same
            wiring = plan[rn.name]
            wf = self.run_dir / f"{rn.name}.json"
            wf.write_text(json.dumps({"class": rn.class_path, "params": rn.params, "wiring": wiring.__dict__}))
            self.children[rn.name] = Child(rn, wiring, wf)
        self.processes = group_processes(self.children, process_groups(self.graph))

    def manifest(self) -> Manifest:
        """Nodes, topics, types and endpoints of the running graph."""
        m = graph_manifest(self.graph, self.endpoints, list(self.children.values()), self.liveness, self.outputs)
        if self.clocks is not None:
            m.clocks = {k: st.as_dict() for k, st in self.clocks.stats().items()}
        return m

    # ----- other machines' clocks ------------------------------------------------------------
    def _start_clocks(self) -> None:
        """With --machine in a graph of several machines: the time service (launch.machine_clock)."""
        if self.machine is None or len(machine_addresses(self.graph)) < 2:
            return
        sec = self.graph.spec.security
        key = CurveKeys.load(sec.key, sec.authorized).secret if sec.curve else None
        try:
            self.clocks = MachineClocks(self.graph, self.machine, key)
        except OSError as exc:
            self.say(f"[launch] clock exchange with the other machines off: cannot listen ({exc})")

    def _tend_clocks(self) -> None:
        """Answer and ask; tell the nodes (at most once a second) and the console (when it moved)."""
        self.clocks.probe()
        for p in self.clocks.silent_peers(after_s=10.0):
            self.say(f"[launch] machine {p.machine} does not answer time requests at {p.address[0]}:{p.address[1]} "
                     "(udp) yet: latencies from it stay uncorrected until it does")
        if not self.clocks.serve():
            return
        stats = self.clocks.stats()
        for m, st in stats.items():
            last = self._clocks_said.get(m)
            if st.samples >= 8 and (last is None or abs(st.offset_ns - last) > 1e6):
                self._clocks_said[m] = st.offset_ns
                self.say(f"[launch] clock of machine {m}: {st.offset_ns / 1e6:+.3f} ms from this one's "
                         f"(round trip {st.delay_ms:.3f} ms)")
        now = time.monotonic()
        if now - self._clocks_told >= 1.0 and any(st.samples >= 8 for st in stats.values()):
            self._clocks_told = now
            msg = CLOCKS + json.dumps({"senders": self.clocks.sender_offsets(),
                                       "machines": {m: st.as_dict() for m, st in stats.items() if st.samples}}).encode()
            for name in self.children:
                self._send(name, msg)

    # ----- logging --------------------------------------------------------------------------
    def say(self, text: str) -> None:
        with self._out_lock:
            self.out.write(text + "\n")
            self.out.flush()

    def _pump(self, name: str, stream: IO[bytes]) -> None:
        for raw in iter(stream.readline, b""):
            self.say(f"[{name}] {raw.decode(errors='replace').rstrip()}")
        stream.close()

    # ----- processes --------------------------------------------------------------------------
    def _spawn(self, p: Process) -> None:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        p.proc = subprocess.Popen(
            [sys.executable, "-m", "mocapgraph.bus.runtime", *(str(c.wiring_file) for c in p.members)],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
            env=env, preexec_fn=p.before_exec, start_new_session=True,
        )
        for c in p.members:
            c.ready = c.started = c.stopped = False
        p.started_at = time.monotonic()
        # a group's log lines name their node after the process (the runtime's format for groups)
        t = threading.Thread(target=self._pump, args=(p.members[0].node.name if p.solo else p.name, p.proc.stdout),
                             daemon=True)
        t.start()
        p.threads.append(t)

    def _send(self, name: str, *frames: bytes) -> None:
        try:
            self.control.send_multipart([name.encode(), *frames], zmq.NOBLOCK)
        except zmq.ZMQError:
            pass

    def _serve_control(self) -> list[str]:
        readied = []
        while True:
            try:
                ident, *frames = self.control.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return readied
            name = ident.decode()
            child = self.children.get(name)
            if child is None or not frames:
                continue
            if frames[0] == READY:
                child.ready = True
                readied.append(name)
            elif frames[0] == STARTED:
                child.started = True
            elif frames[0] == BYE:
                child.stopped = True
                if not child.process.solo and not self._stop_requested and child.proc.poll() is None:
                    self.say(f"[launch] node {name} stopped (process {child.process.name} serves its other nodes on)")

    def _serve_master(self) -> None:
        self.master_server.serve(self.manifest)

    def _bind_master(self) -> None:
        try:
            self.master_server = ManifestServer(self.master, self.ctx)
        except ManifestBusyError as exc:
            raise LaunchError(str(exc)) from None
        self.master_sock = self.master_server.socket

    def start(self) -> None:
        """Start every node and wait until the whole graph is ready, then let it run."""
        self.control = self.ctx.socket(zmq.ROUTER)
        self.control.setsockopt(zmq.LINGER, 0)
        self.control.bind(self.control_ep)
        self._bind_master()
        t0 = time.monotonic()
        for p in self.processes.values():
            self._spawn(p)
        while not all(c.ready for c in self.children.values()):
            self._serve_control()
            self._serve_master()
            for p in self.processes.values():
                if p.proc.poll() is not None:
                    raise LaunchError(f"{p.label} exited with code {p.proc.returncode} during start-up")
            if time.monotonic() - t0 > READY_TIMEOUT_S:
                late = [c.node.name for c in self.children.values() if not c.ready]
                raise LaunchError(f"nodes not ready after {READY_TIMEOUT_S:.0f} s: {', '.join(late)}")
            if self._stop_requested:
                raise LaunchError("interrupted during start-up")
            self.control.poll(10)
        # Downstream first, each acknowledged before the next: a node is in its started state
        # (calibration in auto mode, say) before any source upstream of it sends a frame.
        for name in reversed([n for n in shutdown_order(self.graph) if n in self.children]):
            self._send(name, START)
            t_ack = time.monotonic() + START_ACK_TIMEOUT_S
            while not self.children[name].started and time.monotonic() < t_ack:
                if self.children[name].proc.poll() is not None:
                    break
                zmq.select([self.control, self.master_sock], [], [], 0.005)
                self._serve_control()
                self._serve_master()  # a node's on_start may ask for the manifest (a recorder's metadata)
        self.ready_time_s = time.monotonic() - t0
        self._watch_diagnostics()
        self._start_clocks()
        grouped = len(self.processes) != len(self.children)
        self.say(f"[launch] {len(self.children)} nodes ready in {self.ready_time_s:.2f} s "
                 + (f"in {len(self.processes)} processes " if grouped else "") + f"(manifest at {self.master})")

    def _watch_diagnostics(self) -> None:
        """Subscribe to every node's diagnostics: their silence is how a stopped node shows."""
        sec = self.graph.spec.security
        self.diag = diagnostics_socket(self.ctx, self.endpoints.values(),
                                       CurveKeys.load(sec.key, sec.authorized) if sec.curve else None)
        now = time.monotonic()
        for name in self.children:
            self.liveness.watch(name, now)

    def _check_liveness(self, now: float) -> None:
        if self.diag is None:
            return
        for line in heard_lines(self.liveness, self.outputs, drain_diagnostics(self.diag), now, self.children):
            self.say(line)
        running = [n for n, c in self.children.items() if c.proc is not None and c.proc.poll() is None and not c.stopped]
        for name, silent in self.liveness.newly_stalled(now, running):
            self.say(f"[launch] node {name} stalled: no diagnostics for {silent:.1f} s "
                     f"(pid {self.children[name].proc.pid}; stopped, or stuck in a handler?)")

    def _watch(self) -> None:
        now = time.monotonic()
        self._check_liveness(now)
        for name in self._serve_control():
            self._send(name, START)  # a respawned node joins the running graph
        for p in self.processes.values():
            if p.respawn_due(now):
                self.say(f"[launch] respawning {p.label.removeprefix('node ')} (restart {p.restarts})")
                self._spawn(p)
                for c in p.members:
                    self.liveness.watch(c.node.name, now + STALL_S)  # start-up time is not silence
                    self.outputs.forget(c.node.name)
                continue
            code = p.poll_exit(now, self._stop_requested)
            if code is None:
                continue
            self.say(f"[launch] {p.label} exited with code {code}")
            if p.respawn_at is None and p.required:
                self.say(f"[launch] required node {', '.join(c.node.name for c in p.members if c.node.spec.required)} "
                         f"died{'' if p.solo else ' (with its process)'}: stopping the graph")
                self._exit_code = 1
                self._stop_requested = True

    def spin(self) -> int:
        """Supervise until stop is requested or every node has finished; returns the exit code."""
        while not self._stop_requested:
            self._watch()
            self._serve_master()
            if self.clocks is not None:
                self._tend_clocks()
            if all(p.finished and p.respawn_at is None for p in self.processes.values()):
                self.say("[launch] every node has finished")
                break
            zmq.select([self.control, self.master_sock] + ([self.diag] if self.diag is not None else [])
                       + ([self.clocks.fileno()] if self.clocks is not None else []), [], [], 0.05)
        return self._exit_code

    def request_stop(self) -> None:
        self._stop_requested = True

    def shutdown(self) -> None:
        """Stop nodes upstream first; escalate to SIGTERM then SIGKILL for stragglers."""
        t0 = time.monotonic()
        for p in self.processes.values():
            p.respawn_at = None
        for name in [n for n in shutdown_order(self.graph) if n in self.children]:
            c = self.children[name]
            p = c.process
            if c.proc is None or c.proc.poll() is not None:
                continue
            self._send(name, STOP)
            if any(m.proc is not None and not m.stopped and m is not c for m in p.members):
                # others of its process still serve: wait for this node's BYE only (they drain on)
                self._await_bye(c, STOP_TIMEOUT_S / 2)
                continue
            if not _wait(c.proc, STOP_TIMEOUT_S / 2):
                c.proc.terminate()
                if not _wait(c.proc, STOP_TIMEOUT_S / 2):
                    c.proc.kill()
                    c.proc.wait()
        for p in self.processes.values():
            for t in p.threads:
                t.join(timeout=1.0)
        self.stop_time_s = time.monotonic() - t0
        self.say(f"[launch] stopped in {self.stop_time_s:.2f} s")
        if hasattr(self, "control"):
            self.control.close(0)
        if self.diag is not None:
            self.diag.close(0)
        if hasattr(self, "master_server"):
            self.master_server.close()
        if self.clocks is not None:
            self.clocks.close()
        shutil.rmtree(self.run_dir, ignore_errors=True)

    def _await_bye(self, c: Child, timeout_s: float) -> None:
        """Until ``c`` said BYE (it left its loop), its process ended, or ``timeout_s`` passed."""
        t_end = time.monotonic() + timeout_s
        while not c.stopped and c.proc.poll() is None and time.monotonic() < t_end:
            zmq.select([self.control], [], [], 0.005)
            self._serve_control()

    def kill_all(self) -> None:
        for p in self.processes.values():
            if p.proc is not None and p.proc.poll() is None:
                p.proc.kill()



def graph_manifest(graph: CheckedGraph, endpoints: dict[str, str], children: list[Child],
                   liveness: Liveness, outputs: OutputWatch | None = None) -> Manifest:
    """The manifest of a running graph: every node's topics and endpoints (also those on other
    machines), this launcher's processes, the key files of a CurveZMQ bus."""
    types = graph.topic_types()
    m = Manifest(graph=graph.spec.file)
    sec = graph.spec.security
    if sec.curve:
        m.security = {"key": sec.key, "authorized": sec.authorized}
    for rn in graph.nodes:
        for port, t in rn.outputs.items():
            m.add_publisher(t, types[t], rn.name, endpoints[rn.name], rn.iface.outputs[port].is_latched)
        for port, t in rn.inputs.items():
            m.add_subscriber(t, types.get(t, "*"), rn.name, port)
    for ext in graph.spec.external:
        m.add_publisher(ext.topic, ext.type, "external", ext.endpoint)
    diag = m.topics.pop(DIAGNOSTICS_TOPIC, {"subscribers": []})
    m.topics[DIAGNOSTICS_TOPIC] = {"type": "Diagnostics", "subscribers": diag["subscribers"], "publishers": []}
    for n, e in endpoints.items():
        m.add_publisher(DIAGNOSTICS_TOPIC, "Diagnostics", n, e)
    m.nodes = [NodeEntry(c.node.name, c.node.spec.type, c.node.class_path, c.proc.pid if c.proc else None,
                         endpoints[c.node.name], c.node.params, c.node.inputs, c.node.outputs,
                         c.restarts, bool(c.proc and c.proc.poll() is None),
                         stalled=liveness.is_stalled(c.node.name),
                         stalled_outputs=outputs.stalled_outputs(c.node.name) if outputs else [])
                for c in children]
    return m

def _wait(proc: subprocess.Popen, timeout: float) -> bool:
    try:
        proc.wait(timeout)
        return True
    except subprocess.TimeoutExpired:
        return False


def run_graph(graph: CheckedGraph, master: str | None = None, out: IO[str] | None = None,
              machine: str | None = None) -> int:
    """Launch, supervise and stop a graph (with ``machine``: only that machine's nodes, connected to
    the others'); Ctrl-C / SIGTERM stop it in order. Exit code."""
    sup = Supervisor(graph, master, out, machine)
    hits = {"n": 0}

    def on_signal(signum: int, frame: Any) -> None:
        hits["n"] += 1
        sup.request_stop()
        if hits["n"] >= 3:
            sup.kill_all()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            sup.start()
        except LaunchError as exc:
            sup.say(f"[launch] error: {exc}")
            sup._exit_code = 1
            return 1
        return sup.spin()
    finally:
        sup.shutdown()
        for s, h in old.items():
            signal.signal(s, h)
