"""The `Node` a node author subclasses: declarations, wiring to sockets, the start-up handshake.

A node subclasses `Node`, declares `Input`/`Output`/`Param` class attributes, and implements
``on_<input name>(msg)`` handlers, optionally ``on_start``/``on_stop`` and timers. The runtime:

- binds one XPUB socket for all of the node's outputs; the XPUB sees every subscription, which
  is how latched values reach late joiners and how the start-up handshake knows that every
  subscriber in the graph is connected before the first frame is sent (no slow-joiner loss); it
  applies only subscriptions to the node's own topics (manual mode, `subscriptions`);
- opens one SUB socket per input (so queue depth is per subscription) connected to every
  publisher of its topic (`bound_ports`);
- counts per edge: rate from sender stamps, latency, sequence gaps, rejected frames, and
  publishes them on ``diagnostics`` once a second (`diagnostics`).

The parts live beside this module: `loop` (event loop, timers), `protocol` (launcher control
messages, wiring, parent watchdog), `bound_ports` (publish, receive), `diagnostics`.

Order of events in a node's life: ``__init__`` (params checked) -> sockets set up -> handlers
may already receive messages, latched ones above all (so set up state in ``__init__``, not in
``on_start``) -> ``on_start`` once the whole graph is ready (timers start ticking; sources
publish from here) -> ``on_stop`` -> sockets closed.

Public hooks besides the declarations: `add_timer` (returns a `Timer` with cancel/reschedule),
`call_later` (one shot), `add_reader` for file descriptors (serial ports, UDP sockets),
``Input(raw=True)`` for handlers that take undecoded frames, `OutputPort.publish_frames` for
re-publishing recorded bytes, `bound_port(name)` for a bound port by name (not `port`: a common param name), `begin` to run a node by
hand (the bag player CLI), `input_ports`/`output_ports`/`iface`, `edge_records`.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import replace
from typing import Any, Callable

import zmq

from ..messages import Diagnostics, Message
from ..messages.codec import topic_frame
from .bound_ports import InputPort, OutputPort
from .curve import CurveKeys, make_server, release_authenticator, start_authenticator
from .peer_guard import PeerGuard, limit_inbound
from .subscriptions import Subscriptions
from .diagnostics import (DIAGNOSTICS_PERIOD_S, DIAGNOSTICS_TOPIC, ClockRecord, EdgeRecord, build_diagnostics,
                          input_edge_records)
from .loop import EventLoop, Timer
from .ports import Input, Interface, Output, Param, ParamError, declared_interface
from .protocol import CLOCKS, READY, START, STARTED, STOP, LauncherLink, ParentWatchdog, Wiring

SEND_QUEUE = 1000  # messages per subscriber held by a publisher before it drops (counted downstream)
LOG_FORMAT = "%(levelname)s %(message)s"
_DIAGNOSTICS_PORT = "__diagnostics__"


def _publisher(ctx: zmq.Context, curve: CurveKeys | None, keys: list[bytes],
               later: Callable[[float, Callable[[], None]], object]) -> tuple[zmq.Socket, PeerGuard]:
    """A node's XPUB socket, not yet bound (``keys``: its output topics' frames), and its peer guard."""
    pub = ctx.socket(zmq.XPUB)
    if curve is not None:
        start_authenticator(ctx, curve)
        make_server(pub, curve)
    pub.setsockopt(zmq.XPUB_VERBOSE, 1)
    # subscriptions in our hands: only those to our own topics are applied (`subscriptions`) ...
    pub.setsockopt(zmq.XPUB_MANUAL, 1)
    limit_inbound(pub, max(map(len, keys + [topic_frame(DIAGNOSTICS_TOPIC)])), curve is not None)
    # ... and a bounded share of them per peer (`peer_guard`); bounded per subscriber too, so a
    # stalled viewer cannot grow this process without limit; a subscriber with no receive limit
    # (a recorder) drains into its own memory and loses nothing
    pub.setsockopt(zmq.SNDHWM, SEND_QUEUE)
    pub.setsockopt(zmq.LINGER, 500)
    return pub, PeerGuard(pub, later)


class NodeConfigError(ValueError):
    """Parameters or wiring that a node cannot run with."""


class Node:
    """Base class of every node. See the module docstring for the contract."""

    #: one-line description shown by ``mocapgraph node list``
    summary: str = ""

    def __init__(self, name: str, params: dict[str, Any] | None = None, wiring: Wiring | None = None) -> None:
        self.name = name
        self.log = logging.getLogger(name)
        iface = self.interface(params or {})
        self.params = self.check_params(params or {}, iface)
        self.wiring = wiring or Wiring(node=name)
        self._iface = iface
        self._ports: dict[str, InputPort | OutputPort] = {}
        self._loop = EventLoop()
        self._started = False
        self._t0 = time.monotonic()
        self._ctx = zmq.Context.instance()
        self._pub: zmq.Socket | None = None
        self._guard: PeerGuard | None = None
        self._subs = Subscriptions(lambda: [p for p in self._ports.values() if isinstance(p, OutputPort)],
                                   self.call_later, lambda: self._loop.timers_on,
                                   lambda: self._guard is not None and self._guard.check())
        self._ready_sent = False
        self._launcher: LauncherLink | None = None
        self._sender_clock_ns: dict[str, int] = {}          # other machines' nodes: their clock - ours
        self._machine_clocks: dict[str, dict[str, Any]] = {}
        self._watchdog = ParentWatchdog()
        self._stop_requested = False
        #: subscriptions to our topics served inside this process (not counted by the XPUB)
        self._local_subscribers: dict[bytes, int] = {}

    # ----- declarations -------------------------------------------------------------------
    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        """Declared inputs, outputs and parameters. Override to shape ports from ``params``."""
        return declared_interface(cls)

    @classmethod
    def check_params(cls, given: dict[str, Any], iface: Interface | None = None) -> dict[str, Any]:
        """Defaults merged with ``given``; raises NodeConfigError naming the bad key."""
        iface = iface or cls.interface(given)
        unknown = sorted(set(given) - set(iface.params))
        if unknown:
            raise NodeConfigError(f"unknown parameter {unknown[0]!r}")
        out = {}
        for key, p in iface.params.items():
            try:
                out[key] = p.check(given[key]) if key in given else p.default
            except ParamError as exc:
                raise NodeConfigError(f"parameter {key!r} {exc}") from None
        return out

    # ----- for subclasses -------------------------------------------------------------------
    def on_start(self) -> None:
        """Called once when the whole graph is ready (sources start publishing here)."""

    def on_stop(self) -> None:
        """Called once on shutdown, before sockets close (flush files here)."""

    def input_handler(self, port_name: str) -> Callable[[Message], Any] | None:
        """The callable that receives messages of an input: ``on_<port name>`` by default."""
        return getattr(self, f"on_{port_name}", None)

    def add_timer(self, period_s: float, callback: Callable[[], Any], first_delay_s: float | None = None) -> Timer:
        """Call ``callback`` every ``period_s`` seconds of monotonic time (no drift), once started."""
        return self._loop.add_timer(period_s, callback, first_delay_s, owner=self)

    def call_later(self, delay_s: float, callback: Callable[[], Any]) -> Timer:
        """Call ``callback`` once, ``delay_s`` seconds from now (timers run once started)."""
        return self._loop.call_later(delay_s, callback, owner=self)

    def add_reader(self, fd: int, callback: Callable[[], Any]) -> None:
        """Call ``callback`` whenever file descriptor ``fd`` (a serial port, a UDP socket) is readable."""
        self._loop.watch(fd, callback, owner=self)

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` (before closing it)."""
        self._loop.unwatch(fd)

    def bound_port(self, name: str) -> InputPort | OutputPort:
        """The bound port declared as ``name`` (after setup); KeyError when there is none."""
        return self._ports[name]

    @property
    def iface(self) -> Interface:
        """This node's declared ports and params (as shaped by its params)."""
        return self._iface

    @property
    def input_ports(self) -> dict[str, InputPort]:
        return {k: p for k, p in self._ports.items() if isinstance(p, InputPort)}

    @property
    def output_ports(self) -> dict[str, OutputPort]:
        """Bound outputs by port name (the runtime's diagnostics output excluded)."""
        return {k: p for k, p in self._ports.items() if isinstance(p, OutputPort) and k in self._iface.outputs}

    @property
    def started(self) -> bool:
        return self._started

    @property
    def stopping(self) -> bool:
        return self._stop_requested

    def request_stop(self) -> None:
        """Leave the event loop after the current callback (a finished file source calls this)."""
        self._stop_requested = True
        self._loop.stopped = True

    @property
    def uptime_s(self) -> float:
        return time.monotonic() - self._t0

    # ----- wiring -----------------------------------------------------------------------------
    def setup(self) -> None:
        """Bind, connect and subscribe according to the wiring."""
        w = self.wiring
        self._curve = CurveKeys.load(w.curve["key"], w.curve["authorized"]) if w.curve else None
        keys = [topic_frame(w.outputs.get(n, {}).get("topic", d.topic)) for n, d in self._iface.outputs.items()]
        self._pub, self._guard = pub, guard = _publisher(self._ctx, self._curve, keys, self.call_later)
        self._loop.watch(guard.monitor, guard.on_monitor, owner=self)
        if w.pub_endpoint:
            pub.bind(w.pub_endpoint)
        else:
            pub.bind("tcp://127.0.0.1:*")
            w.pub_endpoint = pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self._loop.watch(pub, self._on_subscription, owner=self)
        for name, decl in self._iface.outputs.items():
            self._ports[name] = OutputPort(self, decl, w.outputs.get(name, {}).get("topic", decl.topic))
        self._ports[_DIAGNOSTICS_PORT] = OutputPort(
            self, Output(DIAGNOSTICS_TOPIC, Diagnostics, latched=False, name="diagnostics"), DIAGNOSTICS_TOPIC)
        for name, decl in self._iface.inputs.items():
            spec = w.inputs.get(name, {})
            port = InputPort(self, decl, spec.get("topic", decl.topic), spec.get("senders"))
            self._ports[name] = port
            port.handler = self.input_handler(name)
            self._loop.watch(port.open(self._ctx, spec.get("endpoints", []), self._curve), port.on_readable, owner=self)
        for name in (*self._iface.outputs, *self._iface.inputs):   # a handler's self.<port>: a dict lookup, not
            # the declaration's descriptor call; (an attribute of that name the node has wins: bound_port())
            self.__dict__.setdefault(name, self._ports[name])
        if w.control:
            self._launcher = LauncherLink(self._ctx, w.control, self.name)
            self._loop.watch(self._launcher.socket, self._on_control, owner=self)
        self.add_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics)

    def _expected_subscriptions(self) -> dict[bytes, int]:
        want: dict[bytes, int] = {}
        for name, spec in self.wiring.outputs.items():
            port = self._ports.get(name)
            if isinstance(port, OutputPort):
                want[port.topic_key] = want.get(port.topic_key, 0) + int(spec.get("subscribers", 0))
        if self.wiring.diagnostics_subscribers:
            key = topic_frame(DIAGNOSTICS_TOPIC)
            want[key] = want.get(key, 0) + self.wiring.diagnostics_subscribers
        for key, n in self._local_subscribers.items():
            want[key] = want.get(key, 0) - n
        return want

    def _on_subscription(self) -> None:
        self._subs.drain(self._pub)
        self.announce_ready()

    def announce_ready(self) -> None:
        """Tell the launcher we are ready once every expected subscriber has subscribed
        (without a launcher: start now)."""
        if self._ready_sent:
            return
        if all(self._subs.counts.get(k, 0) >= n for k, n in self._expected_subscriptions().items()):
            self._ready_sent = True
            if self._launcher is not None:
                self._launcher.send(READY)
            else:
                self._start()

    def _start(self) -> None:
        if not self._started:
            self._started = True
            self._loop.timers_on = True
            self.on_start()
            if self._launcher is not None:
                self._launcher.send(STARTED)

    def _on_control(self) -> None:
        for cmd in self._launcher.received():
            if cmd == START:
                self._start()
            elif cmd == STOP:
                self.request_stop()
            elif cmd.startswith(CLOCKS):
                self._take_clocks(cmd[len(CLOCKS):])

    def _take_clocks(self, data: bytes) -> None:
        """The launcher's measure of the other machines' clocks (launch.machine_clock): each sender
        node's clock minus ours (ns), and per machine offset, delay and jitter."""
        try:
            d = json.loads(data)
            self._sender_clock_ns = {str(k): int(v) for k, v in d.get("senders", {}).items()}
            self._machine_clocks = {str(k): dict(v) for k, v in d.get("machines", {}).items()}
        except (ValueError, TypeError, AttributeError) as exc:
            self.log.warning("clocks from the launcher not understood (%s)", exc)

    # ----- diagnostics ------------------------------------------------------------------------
    def edge_records(self) -> list[EdgeRecord]:
        """Every incoming edge's figures (sources add their device streams); the latency of an edge
        from another machine counts that machine's clock offset (a publish stamp is its clock)."""
        recs = [r for p in self._ports.values() if isinstance(p, InputPort)
                for r in input_edge_records(p.topic, p.stats)]
        if self._sender_clock_ns:
            recs = [replace(r, latency_ms=r.latency_ms + off / 1e6, latency_max_ms=r.latency_max_ms + off / 1e6)
                    if (off := self._sender_clock_ns.get(r.sender)) else r for r in recs]
        return recs

    def clock_records(self) -> list[ClockRecord]:
        """Clocks this node maps onto its own: the other machines' (device readers add their devices')."""
        return [ClockRecord(f"machine:{m}", -float(c.get("offset_ns", math.nan)) / 1e6, math.nan,
                            float(c.get("jitter_ms", math.nan))) for m, c in self._machine_clocks.items()]

    def diagnostics(self) -> Diagnostics:
        """Current statistics as a message."""
        outs = [(p.topic, p.seq) for p in self._ports.values() if isinstance(p, OutputPort)]
        return build_diagnostics(self.name, self.uptime_s, self.edge_records(), outs, self.clock_records())

    def _publish_diagnostics(self) -> None:
        self._ports[_DIAGNOSTICS_PORT].publish(self.diagnostics())
        if self.wiring.control and self._watchdog.parent_gone():
            self.log.error("launcher is gone; stopping")
            self.request_stop()

    def spin_once(self, timeout_s: float) -> None:
        """Serve sockets and timers for at most ``timeout_s`` seconds."""
        self._loop.spin_once(timeout_s)

    def begin(self) -> None:
        """Set up sockets and announce readiness (a node run without a launcher starts at once)."""
        self.setup()
        self.announce_ready()

    def run(self) -> int:
        """Set up, serve until stopped, clean up. Returns the process exit code."""
        from .process import serve
        return serve([self])

    def join_loop(self, loop: EventLoop) -> None:
        """Serve from ``loop`` (shared by the nodes of one process) instead of our own: call before setup."""
        loop.adopt(self._loop)
        self._loop = loop

    def finish(self) -> None:
        """on_stop, then close our sockets and take our registrations off the loop."""
        try:
            self.on_stop()
        finally:
            self._loop.forget(self)
            self.close()

    def close(self) -> None:
        for port in self._ports.values():
            if isinstance(port, InputPort):
                port.closed = True
                if port.socket is not None:
                    port.socket.close(0)
        if self._launcher is not None:
            self._launcher.close()
        if self._guard is not None:
            self._guard.close()
        if self._pub is not None:
            self._pub.close()
        if self._curve is not None:
            release_authenticator(self._ctx)


__all__ = ["Node", "Input", "Output", "Param", "Wiring", "Timer", "NodeConfigError",
           "InputPort", "OutputPort", "DIAGNOSTICS_TOPIC"]
