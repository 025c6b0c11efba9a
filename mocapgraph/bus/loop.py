"""The event loop: poll sockets and file descriptors, run timers, deliver in-process messages.

One loop serves one process: a single node, or the nodes of a launch graph's ``process:`` group,
which share it. Every socket, descriptor and timer is registered with its owner (a node), so a
node that stops alone can take its own registrations away (`forget`). Messages between nodes of
one process skip ZeroMQ (`bound_ports.OutputPort._send_local`): delivered inside ``publish``, or,
when the publishing handler is itself being fed in process, queued here (`local_ready`) and
delivered right after the outer handler returns (so no handler is ever re-entered).
"""
from __future__ import annotations

import time
from typing import Any, Callable

import zmq


class Timer:
    """A callback on monotonic time: periodic, or one-shot when ``period`` is None."""

    __slots__ = ("due", "period", "callback", "owner", "_loop")

    def __init__(self, loop: "EventLoop", due: float, period: float | None, callback: Callable[[], Any],
                 owner: Any = None) -> None:
        self.due = due
        self.period = period
        self.callback = callback
        self.owner = owner
        self._loop = loop

    def cancel(self) -> None:
        """Stop calling back (safe to call twice, and after a one-shot fired)."""
        if self in self._loop.timers:
            self._loop.timers.remove(self)

    def reschedule(self, due: float) -> None:
        """Next call at monotonic time ``due`` (s); the period applies after it."""
        self.due = due


#: rounds of in-process deliveries per call of `run_local` (nodes of one process feeding each
#: other in a cycle must not keep the loop from its sockets; what is left goes on the next turn)
LOCAL_ROUNDS = 16


class EventLoop:
    """Polls registered sockets/fds, runs due timers (only once ``timers_on``) and delivers
    in-process messages. ``stopped``: return from `spin_once` now (a node asked to stop)."""

    def __init__(self) -> None:
        self.poller = zmq.Poller()
        # What to call when poll says a socket or file descriptor is readable, and whose it is.
        self.dispatch: dict[Any, Callable[[], Any]] = {}
        self.owners: dict[Any, Any] = {}
        self.timers: list[Timer] = []
        self.stopped = False
        self.timers_on = False
        #: input ports holding in-process messages, in arrival order (a dict as an ordered set);
        #: each has an ``on_local()`` that takes them
        self.local_ready: dict[Any, None] = {}
        #: an in-process delivery is running: what its handler publishes waits in ``local_ready``
        self.delivering = False

    def watch(self, sock: Any, callback: Callable[[], Any], owner: Any = None) -> None:
        """Call ``callback`` whenever ``sock`` (a zmq socket or a file descriptor) is readable."""
        self.poller.register(sock, zmq.POLLIN)
        self.dispatch[sock] = callback
        self.owners[sock] = owner

    def unwatch(self, sock: Any) -> None:
        self.owners.pop(sock, None)
        if self.dispatch.pop(sock, None) is not None:
            try:
                self.poller.unregister(sock)
            except KeyError:
                pass

    def adopt(self, other: "EventLoop") -> None:
        """Take over every registration of ``other`` (a node's own loop, before it joins a shared one)."""
        for sock, callback in list(other.dispatch.items()):
            owner = other.owners.get(sock)
            other.unwatch(sock)
            self.watch(sock, callback, owner)
        for t in other.timers:
            t._loop = self
            self.timers.append(t)
        other.timers = []

    def forget(self, owner: Any) -> None:
        """Drop every socket, descriptor and timer registered by ``owner`` (a node that stopped)."""
        for sock in [s for s, o in self.owners.items() if o is owner]:
            self.unwatch(sock)
        self.timers = [t for t in self.timers if t.owner is not owner]
        for port in [p for p in self.local_ready if getattr(p, "node", None) is owner]:
            del self.local_ready[port]

    def add_timer(self, period_s: float, callback: Callable[[], Any], first_delay_s: float | None = None,
                  owner: Any = None) -> Timer:
        """Every ``period_s`` seconds (no drift); a timer that fell behind skips ticks, never bursts."""
        t = Timer(self, time.monotonic() + (period_s if first_delay_s is None else first_delay_s), period_s,
                  callback, owner)
        self.timers.append(t)
        return t

    def call_later(self, delay_s: float, callback: Callable[[], Any], owner: Any = None) -> Timer:
        """Call ``callback`` once, ``delay_s`` seconds from now (cancel() before then to drop it)."""
        t = Timer(self, time.monotonic() + delay_s, None, callback, owner)
        self.timers.append(t)
        return t

    def run_local(self) -> None:
        """Deliver the in-process messages waiting (and those their handlers publish, for a few rounds)."""
        for _ in range(LOCAL_ROUNDS):
            ready = self.local_ready
            if not ready:
                return
            self.local_ready = {}
            for port in ready:
                port.on_local()   # at the loop's level: what it publishes goes straight on
                if self.stopped:
                    # the rest waits for the next turn (the node that asked to stop is finished first)
                    for p in ready:
                        if p.has_local() and not p.node.stopping:
                            self.local_ready[p] = None
                    return

    def spin_once(self, timeout_s: float) -> None:
        """Serve in-process messages, sockets and timers for at most ``timeout_s`` seconds."""
        if self.local_ready:
            self.run_local()
            if self.stopped:
                return
        now = time.monotonic()
        due = min((t.due for t in self.timers), default=now + timeout_s) if self.timers_on else now + timeout_s
        wait = 0.0 if self.local_ready else max(0.0, min(due, now + timeout_s) - now)
        # zmq_poll has millisecond resolution: poll short of the deadline, then sleep the rest,
        # so that timer-driven sources keep sub-millisecond timing.
        events = self.poller.poll(int(wait * 1000) if wait > 0.002 else 0)
        dispatch = self.dispatch
        for sock, _ in events:
            handler = dispatch.get(sock)
            if handler is not None:
                handler()
                if self.stopped:
                    return
                if self.local_ready:   # what that handler published for this process, before anything else
                    self.run_local()
                    if self.stopped:
                        return
        if not events and 0 < wait <= 0.002:
            time.sleep(max(0.0, due - time.monotonic()) * 0.9)
        if self.timers_on:
            self.run_timers()

    def run_timers(self) -> None:
        """Run every due timer, earliest first."""
        now = time.monotonic()
        due = [t for t in self.timers if t.due <= now]
        if len(due) > 1:
            due.sort(key=lambda t: t.due)
        for t in due:
            if t not in self.timers:
                continue  # cancelled by an earlier callback
            if t.period is None:
                self.timers.remove(t)
                t.callback()
                if self.local_ready:
                    self.run_local()
                if self.stopped:
                    return
                continue
            t.due += t.period
            if t.due < now:  # fell behind: skip, do not burst
                t.due = now + t.period
            planned = t.due
            t.callback()
            if t.due == planned:  # not rescheduled by the callback itself
                after = time.monotonic()
                if planned < after:  # the callback outlasted its period: skip what it overran
                    t.due = after + t.period
            if self.local_ready:
                self.run_local()
            if self.stopped:
                return
