"""The node runtime: sockets, event loop, timers, latched topics, statistics, shutdown.

A node subclasses `Node`, declares `Input`/`Output`/`Param` class attributes, and implements
``on_<input name>(msg)`` handlers, optionally ``on_start``/``on_stop`` and timers. The runtime:

- binds one XPUB socket for all of the node's outputs; the XPUB sees every subscription, which
  is how latched values reach late joiners and how the start-up handshake knows that every
  subscriber in the graph is connected before the first frame is sent (no slow-joiner loss);
- opens one SUB socket per input (so queue depth is per subscription) connected to every
  publisher of its topic;
- counts per edge: rate from sender stamps, latency, sequence gaps, rejected frames, and
  publishes them on ``diagnostics`` once a second.

Order of events in a node's life: ``__init__`` (params checked) -> sockets set up -> handlers
may already receive messages, latched ones above all (so set up state in ``__init__``, not in
``on_start``) -> ``on_start`` once the whole graph is ready (timers start ticking; sources
publish from here) -> ``on_stop`` -> sockets closed.

Public hooks besides the declarations: `add_timer` (returns a `Timer` with cancel/reschedule),
`add_reader` for file descriptors (serial ports, UDP sockets), ``Input(raw=True)`` for handlers
that take undecoded frames, `OutputPort.publish_frames` for re-publishing recorded bytes,
`begin` to run a node by hand (the bag player CLI), `input_ports`/`output_ports`/`iface`.
"""
from __future__ import annotations

import gc
import json
import logging
import os
import resource
import signal
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import zmq

from ..messages import DecodeError, Diagnostics, Envelope, Message, decode_envelope, decode_payload, encode
from ..messages.codec import topic_frame
from ..messages.registry import UnknownTypeError, lookup
from .ports import Input, Interface, Output, Param, ParamError
from .stats import InputStats

DIAGNOSTICS_TOPIC = "diagnostics"
# Plain ints: pyzmq's enum flags cost an enum operation per frame on the hot path.
_SNDMORE = int(zmq.SNDMORE)
_NOBLOCK = int(zmq.NOBLOCK)
_POLLIN = int(zmq.POLLIN)
_EVENTS = int(zmq.EVENTS)
DIAGNOSTICS_PERIOD_S = 1.0
SEND_QUEUE = 1000  # messages per subscriber held by a publisher before it drops (counted downstream)
LOG_FORMAT = "%(levelname)s %(message)s"


class NodeConfigError(ValueError):
    """Parameters or wiring that a node cannot run with."""


@dataclass
class Wiring:
    """How the launcher connects one node: its endpoint, its topics and their publishers.

    inputs: input name -> {"topic": str, "endpoints": [publisher endpoints]}
    outputs: output name -> {"topic": str, "subscribers": expected subscriber count}
    """

    node: str
    pub_endpoint: str = ""
    inputs: dict[str, dict[str, Any]] = field(default_factory=dict)
    outputs: dict[str, dict[str, Any]] = field(default_factory=dict)
    control: str = ""
    diagnostics_subscribers: int = 0

    def to_json(self) -> str:
        return json.dumps(self.__dict__)

    @classmethod
    def from_json(cls, text: str) -> "Wiring":
        return cls(**json.loads(text))


class Timer:
    """A periodic callback on monotonic time; returned by `Node.add_timer`."""

    __slots__ = ("due", "period", "callback", "_node")

    def __init__(self, node: "Node", due: float, period: float, callback: Callable[[], Any]) -> None:
        self.due = due
        self.period = period
        self.callback = callback
        self._node = node

    def cancel(self) -> None:
        """Stop calling back (safe to call twice)."""
        if self in self._node._timers:
            self._node._timers.remove(self)

    def reschedule(self, due: float) -> None:
        """Next call at monotonic time ``due`` (s); the period applies after it."""
        self.due = due


class OutputPort:
    """A bound output: ``publish(msg)`` sends it to every subscriber of its topic."""

    def __init__(self, node: "Node", decl: Output, topic: str) -> None:
        self.node = node
        self.decl = decl
        self.topic = topic
        self.latched = decl.is_latched
        self.seq = 0
        self.last_frames: list | None = None
        self._topic_frame = topic_frame(topic)

    def publish(self, msg: Message, capture_ns: int | None = None) -> None:
        """Send ``msg``. ``capture_ns`` is when the data was captured (defaults to now)."""
        if not isinstance(msg, self.decl.msg_type):
            raise TypeError(f"{self.decl.name} publishes {self.decl.type_name}, not {type(msg).__name__}")
        self.seq += 1
        frames = encode(self.topic, msg, self.seq, time.time_ns() if capture_ns is None else capture_ns,
                        self.node.name, None, self.latched)
        if self.latched:
            frames = [bytes(f) for f in frames]  # keep a copy we own for resends
            self.last_frames = frames
        self._send(frames)

    def publish_frames(self, frames: list, latched: bool = False) -> None:
        """Send already-encoded frames (a bag player's recorded bytes) on this port's topic.

        The header is sent as given (its sequence number and stamps are the caller's); frame 0
        is replaced by this port's topic so that remaps apply.
        """
        frames = list(frames)
        frames[0] = self._topic_frame
        if self.latched or latched:
            frames = [bytes(f) for f in frames]
            self.last_frames = frames
        self.seq += 1
        self._send(frames)

    def _send(self, frames: list) -> None:
        send = self.node._pub.send
        copy = len(frames[-1]) < 65536  # zero-copy pays off only for large payloads
        for f in frames[:-1]:
            send(f, _SNDMORE, copy=copy)
        send(frames[-1], 0, copy=copy)


class InputPort:
    """A bound input: the latest message, its envelope, and statistics."""

    def __init__(self, node: "Node", decl: Input, topic: str) -> None:
        self.node = node
        self.decl = decl
        self.topic = topic
        self.latest: Message | None = None
        self.envelope: Envelope | None = None
        self.stats = InputStats()
        self.socket: zmq.Socket | None = None
        self.handler: Callable[..., Any] | None = None


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
        self._timers: list[Timer] = []
        # What to call when poll says a socket or file descriptor is readable.
        self._dispatch: dict[Any, Callable[[], Any]] = {}
        self._stop = False
        self._started = False
        self._t0 = time.monotonic()
        self._ctx = zmq.Context.instance()
        self._pub: zmq.Socket | None = None
        self._poller = zmq.Poller()
        self._sub_counts: dict[bytes, int] = {}
        self._ready_sent = False
        self._control: zmq.Socket | None = None
        self._parent_pid = os.getppid()

    # ----- declarations -------------------------------------------------------------------
    @classmethod
    def interface(cls, params: dict[str, Any]) -> Interface:
        """Declared inputs, outputs and parameters. Override to shape ports from ``params``."""
        iface = Interface()
        for klass in reversed(cls.__mro__):
            for key, value in vars(klass).items():
                if isinstance(value, Input):
                    iface.inputs[key] = value
                elif isinstance(value, Output):
                    iface.outputs[key] = value
                elif isinstance(value, Param):
                    iface.params[key] = value
        return iface

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
        """Call ``callback`` every ``period_s`` seconds of monotonic time (no drift), once started.

        Due timers run earliest-due first; a timer that fell behind skips ticks rather than
        bursting.
        """
        t = Timer(self, time.monotonic() + (period_s if first_delay_s is None else first_delay_s), period_s,
                  callback)
        self._timers.append(t)
        return t

    def cancel_timer(self, timer: Timer) -> None:
        timer.cancel()

    def add_reader(self, fd: int, callback: Callable[[], Any]) -> None:
        """Call ``callback`` whenever file descriptor ``fd`` (a serial port, a UDP socket) is readable."""
        self._poller.register(fd, zmq.POLLIN)
        self._dispatch[fd] = callback

    def remove_reader(self, fd: int) -> None:
        """Stop watching ``fd`` (before closing it)."""
        if self._dispatch.pop(fd, None) is not None:
            try:
                self._poller.unregister(fd)
            except KeyError:
                pass

    @property
    def iface(self) -> Interface:
        """This node's declared ports and params (as shaped by its params)."""
        return self._iface

    @property
    def input_ports(self) -> dict[str, "InputPort"]:
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
        return self._stop

    def request_stop(self) -> None:
        """Leave the event loop after the current callback (a finished file source calls this)."""
        self._stop = True

    @property
    def uptime_s(self) -> float:
        return time.monotonic() - self._t0

    # ----- runtime ----------------------------------------------------------------------------
    def setup(self) -> None:
        """Bind, connect and subscribe according to the wiring."""
        w = self.wiring
        self._pub = self._ctx.socket(zmq.XPUB)
        self._pub.setsockopt(zmq.XPUB_VERBOSE, 1)
        # Bounded per subscriber, so a stalled viewer cannot grow this process without limit; a
        # subscriber with no receive limit (a recorder) drains into its own memory and loses nothing.
        self._pub.setsockopt(zmq.SNDHWM, SEND_QUEUE)
        self._pub.setsockopt(zmq.LINGER, 500)
        if w.pub_endpoint:
            self._pub.bind(w.pub_endpoint)
        else:
            self._pub.bind("tcp://127.0.0.1:*")
            w.pub_endpoint = self._pub.getsockopt_string(zmq.LAST_ENDPOINT)
        self._poller.register(self._pub, zmq.POLLIN)
        self._dispatch[self._pub] = self._on_subscription
        for name, decl in self._iface.outputs.items():
            topic = w.outputs.get(name, {}).get("topic", decl.topic)
            self._ports[name] = OutputPort(self, decl, topic)
        self._ports["__diagnostics__"] = OutputPort(
            self, Output(DIAGNOSTICS_TOPIC, Diagnostics, latched=False, name="diagnostics"), DIAGNOSTICS_TOPIC
        )
        for name, decl in self._iface.inputs.items():
            spec = w.inputs.get(name, {})
            port = InputPort(self, decl, spec.get("topic", decl.topic))
            self._ports[name] = port
            port.handler = self.input_handler(name)
            sock = self._ctx.socket(zmq.SUB)
            sock.setsockopt(zmq.RCVHWM, 0 if decl.queue <= 0 else decl.queue)
            sock.setsockopt(zmq.RECONNECT_IVL, 20)
            sock.setsockopt(zmq.RECONNECT_IVL_MAX, 500)
            sock.setsockopt(zmq.LINGER, 0)
            sock.setsockopt(zmq.SUBSCRIBE, topic_frame(port.topic))
            for ep in spec.get("endpoints", []):
                sock.connect(ep)
            port.socket = sock
            self._poller.register(sock, zmq.POLLIN)
            self._dispatch[sock] = (lambda p=port: self._on_input(p))
        if w.control:
            self._control = self._ctx.socket(zmq.DEALER)
            self._control.setsockopt(zmq.IDENTITY, self.name.encode())
            self._control.setsockopt(zmq.LINGER, 200)
            self._control.connect(w.control)
            self._poller.register(self._control, zmq.POLLIN)
            self._dispatch[self._control] = self._on_control
            self._control.send_multipart([b"hello", str(os.getpid()).encode()])
        self.add_timer(DIAGNOSTICS_PERIOD_S, self._publish_diagnostics)

    def _expected_subscriptions(self) -> dict[bytes, int]:
        want: dict[bytes, int] = {}
        for name, spec in self.wiring.outputs.items():
            port = self._ports.get(name)
            if isinstance(port, OutputPort):
                key = topic_frame(port.topic)
                want[key] = want.get(key, 0) + int(spec.get("subscribers", 0))
        if self.wiring.diagnostics_subscribers:
            key = topic_frame(DIAGNOSTICS_TOPIC)
            want[key] = want.get(key, 0) + self.wiring.diagnostics_subscribers
        return want

    def _check_ready(self) -> None:
        if self._ready_sent:
            return
        want = self._expected_subscriptions()
        if all(self._sub_counts.get(k, 0) >= n for k, n in want.items()):
            self._ready_sent = True
            if self._control is not None:
                self._control.send_multipart([b"ready"])
            else:
                self._start()

    def _start(self) -> None:
        if not self._started:
            self._started = True
            self.on_start()
            if self._control is not None:
                self._control.send_multipart([b"started"])

    def _on_subscription(self) -> None:
        while True:
            try:
                ev = self._pub.recv(zmq.NOBLOCK)
            except zmq.Again:
                break
            if not ev or ev[0] != 1:
                continue
            key = ev[1:]
            self._sub_counts[key] = self._sub_counts.get(key, 0) + 1
            for port in self._ports.values():
                if isinstance(port, OutputPort) and port.last_frames is not None and port._topic_frame == key:
                    self._pub.send_multipart(port.last_frames)
        self._check_ready()

    def _on_control(self) -> None:
        while True:
            try:
                frames = self._control.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                break
            cmd = frames[0]
            if cmd == b"start":
                self._start()
            elif cmd == b"stop":
                self._stop = True

    def _on_input(self, port: InputPort) -> None:
        sock = port.socket
        newest: tuple[Envelope, list[bytes]] | None = None
        for i in range(256):  # bounded so one busy input cannot starve the others
            # Poll said readable for the first; ask before the others: a raised zmq.Again costs
            # more than the message itself.
            if i and not sock.getsockopt(_EVENTS) & _POLLIN:
                break
            try:
                frames = sock.recv_multipart(_NOBLOCK)
            except zmq.Again:
                break
            now = time.time_ns()
            try:
                env = decode_envelope(frames)
            except DecodeError as exc:
                port.stats.rejected += 1
                self._reject(port, exc)
                continue
            if env.topic != port.topic:
                continue
            edge = port.stats.edge(env.topic, env.sender)
            if not edge.accept(env.seq, env.publish_ns, now):
                continue
            if port.decl.raw:
                port.envelope = env
                if port.handler is not None:
                    port.handler(env, frames)
                continue
            if port.decl.latest_only:
                newest = (env, frames)
                continue
            self._deliver(port, env, frames)
            if self._stop:
                return
        if newest is not None:
            self._deliver(port, *newest)

    def _deliver(self, port: InputPort, env: Envelope, frames: list[bytes]) -> None:
        want = port.decl.msg_type
        try:
            cls = lookup(env.type_name) if want is None else want
            if want is not None and env.type_name != want.type_name:
                raise DecodeError(f"type {env.type_name} where {want.type_name} was expected")
            msg = decode_payload(cls, env, frames)
        except (DecodeError, UnknownTypeError) as exc:
            port.stats.rejected += 1
            self._reject(port, exc)
            return
        port.latest = msg
        port.envelope = env
        if port.handler is not None:
            port.handler(msg)

    def _reject(self, port: InputPort, exc: Exception) -> None:
        n = port.stats.rejected
        if n <= 5 or n % 1000 == 0:  # logged, but never a flood
            self.log.warning("input %s: rejected frame #%d: %s", port.decl.name, n, exc)

    def diagnostics(self) -> Diagnostics:
        """Current statistics as a message."""
        topics, senders, rate, lat, latmax, recv, gaps, rej = [], [], [], [], [], [], [], []
        for port in self._ports.values():
            if not isinstance(port, InputPort):
                continue
            edges = list(port.stats.edges.values())
            if not edges and port.stats.rejected:
                topics.append(port.topic)
                senders.append("?")
                rate.append(0.0), lat.append(float("nan")), latmax.append(float("nan"))
                recv.append(0), gaps.append(0), rej.append(port.stats.rejected)
            for i, e in enumerate(edges):
                p50, pmax = e.latency_ms()
                topics.append(e.topic)
                senders.append(e.sender)
                rate.append(e.rate_hz())
                lat.append(p50)
                latmax.append(pmax)
                recv.append(e.received)
                gaps.append(e.gaps)
                rej.append(port.stats.rejected if i == 0 else 0)
        outs = [p for p in self._ports.values() if isinstance(p, OutputPort)]
        ru = resource.getrusage(resource.RUSAGE_SELF)
        return Diagnostics(
            node=self.name, pid=os.getpid(), uptime_s=self.uptime_s, cpu_s=ru.ru_utime + ru.ru_stime,
            edge_topics=topics, edge_senders=senders, edge_rate_hz=rate, edge_latency_ms=lat,
            edge_latency_max_ms=latmax, edge_received=recv, edge_gaps=gaps, edge_rejected=rej,
            output_topics=[p.topic for p in outs], output_sent=[p.seq for p in outs],
        )

    def _publish_diagnostics(self) -> None:
        self._ports["__diagnostics__"].publish(self.diagnostics())
        if os.getppid() != self._parent_pid and self.wiring.control:
            self.log.error("launcher is gone; stopping")
            self._stop = True

    def spin_once(self, timeout_s: float) -> None:
        """Serve sockets and timers for at most ``timeout_s`` seconds."""
        now = time.monotonic()
        due = min((t.due for t in self._timers), default=now + timeout_s) if self._started else now + timeout_s
        wait = max(0.0, min(due, now + timeout_s) - now)
        # zmq_poll has millisecond resolution: poll short of the deadline, then sleep the rest,
        # so that timer-driven sources keep sub-millisecond timing.
        events = self._poller.poll(int(wait * 1000) if wait > 0.002 else 0)
        dispatch = self._dispatch
        for sock, _ in events:
            handler = dispatch.get(sock)
            if handler is not None:
                handler()
                if self._stop:
                    return
        if not events and 0 < wait <= 0.002:
            time.sleep(max(0.0, due - time.monotonic()) * 0.9)
        if self._started:
            self._run_timers()

    def _run_timers(self) -> None:
        now = time.monotonic()
        due = [t for t in self._timers if t.due <= now]
        if len(due) > 1:
            due.sort(key=lambda t: t.due)
        for t in due:
            if t not in self._timers:
                continue  # cancelled by an earlier callback
            t.due += t.period
            if t.due < now:  # fell behind: skip, do not burst
                t.due = now + t.period
            planned = t.due
            t.callback()
            if t.due == planned:  # not rescheduled by the callback itself
                after = time.monotonic()
                if planned < after:  # the callback outlasted its period: skip what it overran
                    t.due = after + t.period
            if self._stop:
                return

    def announce_ready(self) -> None:
        """Tell the launcher we are ready once every expected subscriber has subscribed
        (without a launcher: start now)."""
        self._check_ready()

    def begin(self) -> None:
        """Set up sockets and announce readiness (a node run without a launcher starts at once)."""
        self.setup()
        self.announce_ready()

    def run(self) -> int:
        """Set up, serve until stopped, clean up. Returns the process exit code."""
        self.begin()
        # Start-up objects (modules, params, models) need no more scanning by the collector:
        # fewer and shorter pauses on the per-message path.
        gc.freeze()
        try:
            while not self._stop:
                self.spin_once(0.1)
        finally:
            try:
                self.on_stop()
            finally:
                self.close()
        return 0

    def close(self) -> None:
        for port in self._ports.values():
            if isinstance(port, InputPort) and port.socket is not None:
                port.socket.close(0)
        if self._control is not None:
            try:
                self._control.send_multipart([b"bye"], zmq.NOBLOCK)
            except zmq.ZMQError:
                pass
            self._control.close()
        if self._pub is not None:
            self._pub.close()


def install_signal_handlers(node: Node) -> None:
    """SIGINT/SIGTERM end the loop cleanly (on_stop runs, files are flushed)."""

    def handler(signum: int, frame: Any) -> None:
        node._stop = True

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)


def check_params_or_exit(cls: type[Node], params: dict[str, Any]) -> dict[str, Any]:
    try:
        return cls.check_params(params)
    except NodeConfigError as exc:
        raise SystemExit(f"{cls.__name__}: {exc}") from None


__all__ = ["Node", "Input", "Output", "Param", "Wiring", "NodeConfigError", "install_signal_handlers"]
