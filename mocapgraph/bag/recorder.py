"""Recording: bus frames in, bag records out, losses counted from sequence numbers.

Used by the bag recorder node (subscriptions through the node runtime, no high-water mark) and by
``mocapgraph bag record`` against a running graph (subscriptions from the graph's manifest).
Sequence numbers are per (topic, sender) and start at 1: a jump forward is counted as lost
messages and written into the bag (metadata ``mocapgraph.losses``); a repeat (a latched value
resent to another late joiner) is not stored twice; a restart at 1 is a new stream, not loss.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Sequence

from ..messages import Envelope, decode_envelope
from ..messages.codec import DecodeError
from ..messages.sequence import ANOMALY, DUPLICATE, RESTART, sequence_gap
from .writer import BagWriter

FLUSH_PERIOD_S = 0.25


class Recorder:
    """Writes received frames to a `BagWriter`; call `tick()` often (it flushes on time)."""

    def __init__(self, writer: BagWriter, flush_s: float = FLUSH_PERIOD_S) -> None:
        self.writer = writer
        self.flush_s = flush_s
        self._next_flush = time.monotonic() + flush_s
        self._last_seq: dict[tuple[str, str], tuple[int, int]] = {}  # (seq, publish ns)
        self.lost: dict[str, int] = {}
        self.received = 0
        self.duplicates = 0
        self.rejected = 0
        self.restarts = 0

    def receive(self, frames: Sequence[bytes | memoryview], env: Envelope | None = None,
                log_ns: int | None = None) -> bool:
        """Store one message; False when it was a duplicate or malformed (not stored)."""
        if log_ns is None:
            log_ns = time.time_ns()
        if env is None:
            try:
                env = decode_envelope(frames)
            except DecodeError:
                self.rejected += 1
                return False
        key = (env.topic, env.sender)
        last, last_pub = self._last_seq.get(key, (0, 0))
        # A resend repeats the publish stamp too; a restarted sender's new latched value does not.
        lost = sequence_gap(last, env.seq, env.publish_ns == last_pub)
        if lost == DUPLICATE:
            self.duplicates += 1
            return False
        if lost in (RESTART, ANOMALY):
            self.restarts += 1
        elif lost > 0:
            self.lost[env.topic] = self.lost.get(env.topic, 0) + lost
            self.writer.set_losses(self.lost)
        self._last_seq[key] = (env.seq, env.publish_ns)
        self.writer.write_frames(frames, log_ns, env)
        self.received += 1
        return True

    def tick(self, now: float | None = None) -> None:
        """Flush the open chunk when the flush period has passed."""
        now = time.monotonic() if now is None else now
        if now >= self._next_flush:
            self.writer.flush()
            # On the schedule, not from now: a caller that ticks every 50 ms would otherwise
            # stretch every period by up to a tick (0.30 s for 0.25 s).
            self._next_flush += self.flush_s
            if self._next_flush <= now:
                self._next_flush = now + self.flush_s

    def close(self) -> list[Path]:
        self.writer.set_losses(self.lost)
        return self.writer.close()

    def status(self) -> str:
        lost = sum(self.lost.values())
        return (f"{self.received} messages on {len(self.writer.count_by_topic)} topics, "
                f"{self._bytes() / 1e6:.1f} MB, lost {lost}")

    def _bytes(self) -> int:
        total = 0
        for p in self.writer.paths:
            try:
                total += p.stat().st_size
            except OSError:
                pass
        return total
