"""The event loop: poll sockets and file descriptors, run periodic and one-shot timers."""
from __future__ import annotations

import time
from typing import Any, Callable

import zmq


class Timer:
    """A callback on monotonic time: periodic, or one-shot when ``period`` is None."""

    __slots__ = ("due", "period", "callback", "_loop")

    def __init__(self, loop: "EventLoop", due: float, period: float | None, callback: Callable[[], Any]) -> None:
        self.due = due
        self.period = period
        self.callback = callback
        self._loop = loop

    def cancel(self) -> None:
        """Stop calling back (safe to call twice, and after a one-shot fired)."""
        if self in self._loop.timers:
            self._loop.timers.remove(self)

    def reschedule(self, due: float) -> None:
        """Next call at monotonic time ``due`` (s); the period applies after it."""
        self.due = due


class EventLoop:
    """Polls registered sockets/fds and runs due timers; timers tick only once ``timers_on``."""

    def __init__(self) -> None:
        self.poller = zmq.Poller()
        # What to call when poll says a socket or file descriptor is readable.
        self.dispatch: dict[Any, Callable[[], Any]] = {}
        self.timers: list[Timer] = []
        self.stopped = False
        self.timers_on = False

    def watch(self, sock: Any, callback: Callable[[], Any]) -> None:
        """Call ``callback`` whenever ``sock`` (a zmq socket or a file descriptor) is readable."""
        self.poller.register(sock, zmq.POLLIN)
        self.dispatch[sock] = callback

    def unwatch(self, sock: Any) -> None:
        if self.dispatch.pop(sock, None) is not None:
            try:
                self.poller.unregister(sock)
            except KeyError:
                pass

    def add_timer(self, period_s: float, callback: Callable[[], Any], first_delay_s: float | None = None) -> Timer:
        """Every ``period_s`` seconds (no drift); a timer that fell behind skips ticks, never bursts."""
        t = Timer(self, time.monotonic() + (period_s if first_delay_s is None else first_delay_s), period_s,
                  callback)
        self.timers.append(t)
        return t

    def call_later(self, delay_s: float, callback: Callable[[], Any]) -> Timer:
        """Call ``callback`` once, ``delay_s`` seconds from now (cancel() before then to drop it)."""
        t = Timer(self, time.monotonic() + delay_s, None, callback)
        self.timers.append(t)
        return t

    def spin_once(self, timeout_s: float) -> None:
        """Serve sockets and timers for at most ``timeout_s`` seconds."""
        now = time.monotonic()
        due = min((t.due for t in self.timers), default=now + timeout_s) if self.timers_on else now + timeout_s
        wait = max(0.0, min(due, now + timeout_s) - now)
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
            if self.stopped:
                return
