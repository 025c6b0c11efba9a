"""A logging filter that lets through at most BURST records per WINDOW_S, then one summary per window.

A server logs a line or two per connection (the websockets library: "connection open",
"connection rejected (403 Forbidden)", "connection closed"); 3000 token guesses must not become
6000 lines. Records beyond the burst are counted and the next record that passes says how many
were left out.
"""
from __future__ import annotations

import logging
import time

WINDOW_S = 5.0
BURST = 10


class RateLimit(logging.Filter):
    """At most ``burst`` records per ``window_s`` seconds pass; the rest are counted and summarised."""

    def __init__(self, burst: int = BURST, window_s: float = WINDOW_S) -> None:
        super().__init__()
        self.burst = burst
        self.window_s = window_s
        self._start = -window_s
        self._passed = 0
        self.suppressed = 0   # left out since the last summary
        self.total_suppressed = 0

    def filter(self, record: logging.LogRecord) -> bool:
        now = time.monotonic()
        if now - self._start >= self.window_s:
            self._start, self._passed = now, 0
        if self._passed >= self.burst:
            self.suppressed += 1
            self.total_suppressed += 1
            return False
        self._passed += 1
        if self.suppressed:
            record.msg = f"{record.msg} (and {self.suppressed} more such lines left out)"
            self.suppressed = 0
        return True


def limited_logger(name: str, burst: int = BURST, window_s: float = WINDOW_S) -> logging.Logger:
    """The logger ``name`` with a `RateLimit` filter (once, however often this is called)."""
    logger = logging.getLogger(name)
    if not any(isinstance(f, RateLimit) for f in logger.filters):
        logger.addFilter(RateLimit(burst, window_s))
    return logger
