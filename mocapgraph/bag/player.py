"""Playback schedule of a bag: which stored message goes out when. No sockets here: the bag
player node (and through it ``mocapgraph bag play``) sends what `Playback.take_due` returns.

Timing. One clock for all topics: a message is due at ``anchor_wall + (t - anchor_bag) / rate``
where ``t`` is its original publish stamp (MCAP ``publish_time``), so the relative timing of the
recorded graph is reproduced at any rate. Messages go out in recorded (file) order and never
before they are due; ``t`` is clamped to be non-decreasing so a clock step in the recording
cannot reorder them.

What is sent. The stored frames, byte for byte, except:
- the publish stamp is set to the moment of sending (it says when *this* publisher sent it);
- the topic frame when remapped;
- on a loop pass or after a seek, sequence numbers are shifted by a constant per (topic, sender)
  so that they continue from the last one sent (receivers would otherwise drop them as
  duplicates); in the first pass they are the recorded ones, recorded gaps included.
Capture stamps are always the recorded ones, so they jump back on a loop or a backward seek.

Latched topics: before anything else, the last value of every latched topic at or before the start
position (+0.1 s) is handed out (`latched_first`), even when starting paused; a latched topic whose first
value comes later is sent at its time. The node keeps the last value of each latched topic for
late joiners (the bus's XPUB resend).
"""
from __future__ import annotations

import re
import time
from collections import deque
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from ..messages.codec import (header_capture_ns, header_latched, header_sender, header_seq, set_header_publish_ns,
                              set_header_seq)
from .errors import BagError
from .framing import header_of
from .reader import BagReader, RawMessage, TopicInfo

DEFAULT_EXCLUDE = ("diagnostics",)
LAG_WINDOW = 8192
LATCHED_GRACE_NS = 100_000_000
#: a message stamped longer than this before the recorder got it (a latched value published before
#: the recording began) is scheduled as if published this long before it was recorded
MAX_RECORD_DELAY_NS = 200_000_000


def schedule_stamp(raw: RawMessage) -> int:
    """The time a message is due on the bag's axis: its publish stamp, but never long before it was
    recorded (else a latched model published 31 s before the recording made every pass 31 s longer)."""
    t = raw.publish_ns or raw.log_ns
    return max(t, raw.log_ns - MAX_RECORD_DELAY_NS) if raw.log_ns else t


def set_publish_stamp(header: bytearray, now_ns: int | None = None) -> None:
    """Write the publish stamp (now) into a codec header frame in place."""
    set_header_publish_ns(header, time.time_ns() if now_ns is None else now_ns)


@dataclass
class Outgoing:
    """One message ready to send: its (remapped) topic and frames (frames[1] is a writable header)."""

    topic: str
    frames: list
    latched: bool
    bag_ns: int
    due_s: float


def parse_remaps(items: Iterable[str]) -> dict[str, str]:
    """``a:=b`` strings -> {a: b}."""
    out = {}
    for item in items:
        a, sep, b = item.partition(":=")
        if not sep or not a or not b:
            raise ValueError(f"remap {item!r} is not old:=new")
        out[a] = b
    return out


def select_topics(infos: dict[str, TopicInfo], topics: Iterable[str] | None = None,
                  exclude: str | None = None) -> tuple[dict[str, TopicInfo], dict[str, str]]:
    """Topics to play (known types only) and skipped topics with the reason."""
    chosen: dict[str, TopicInfo] = {}
    skipped: dict[str, str] = {}
    wanted = list(topics) if topics else None
    if wanted:
        missing = [t for t in wanted if t not in infos]
        if missing:
            raise BagError(None, f"no topic {missing[0]!r} in the bag (topics: {', '.join(sorted(infos))})")
    rx = re.compile(exclude) if exclude else None
    for name, info in infos.items():
        if wanted is not None and name not in wanted:
            continue
        if wanted is None and name in DEFAULT_EXCLUDE:
            skipped[name] = "recorded diagnostics are not replayed (name it to play it)"
            continue
        if rx is not None and rx.search(name):
            skipped[name] = "excluded"
            continue
        if not info.known:
            skipped[name] = info.problem
            continue
        chosen[name] = info
    return chosen, skipped


class _Feed:
    """The chosen topics read from the bag in file order into a read-ahead buffer of
    (schedule time on the bag's axis ns, message, generation); starts over at the end when
    looping, shifting the schedule times so that they keep growing."""

    def __init__(self, reader: BagReader, topics: list[str], start_ns: int, end_ns: int | None,
                 loop: bool, loop_gap_ns: int) -> None:
        self.reader = reader
        self.topics = topics
        self.start_ns = start_ns      # where every pass starts (the --start position)
        self.end_ns = end_ns
        self.loop = loop
        self.loop_gap_ns = loop_gap_ns  # a typical period between two passes: the last frame is not the first
        self.buf: deque[tuple[int, RawMessage, int]] = deque()
        self.src: Iterator[RawMessage] | None = None
        self.exhausted = False
        self.passes = 0
        self.loops = 0
        self.shift_ns = 0  # added to bag times on loop passes (t keeps growing)
        self.pass_first_ns: int | None = None
        self.last_t = -(1 << 62)
        self.gen = 0  # bumped by every loop and seek: sequence numbers are rebased at the change
        self.src_start_ns = start_ns  # where the open pass began (a seek: elsewhere)
        self.sent_early: set[tuple[str, int]] = set()  # (topic, log ns) handed out by latched_first

    def open(self, start_ns: int) -> None:
        """Read from ``start_ns`` (log time) on."""
        self.src = self.reader.messages(self.topics, start_ns, self.end_ns)
        self.src_start_ns = start_ns
        self.exhausted = False
        self.pass_first_ns = None

    def restart_at(self, start_ns: int) -> None:
        """Forget what was read ahead and read from ``start_ns``, as a new generation (a seek)."""
        self.buf.clear()
        self.shift_ns = 0
        self.last_t = -(1 << 62)
        self.gen += 1
        self.sent_early.clear()
        self.open(start_ns)

    def _next_pass(self) -> None:
        self.passes += 1
        self.loops += 1
        self.gen += 1
        self.open(self.start_ns)

    def _at_end(self) -> bool:
        """The open pass ran out: True when a looping feed has started the next one."""
        if self.loop and self.pass_first_ns is None and self.src_start_ns != self.start_ns:
            # a seek near the end found nothing of the chosen topics: loop means loop
            self._next_pass()
            return True
        if self.loop and self.pass_first_ns is not None:
            self.shift_ns += self.last_t - self.shift_ns - self.pass_first_ns + self.loop_gap_ns
            self._next_pass()
            return True
        self.src = None
        self.exhausted = True
        return False

    def read_one(self) -> bool:
        """Move one message from the bag into the buffer; False at the end (after looping)."""
        while True:
            if self.src is None:
                return False
            try:
                raw = next(self.src)
            except StopIteration:
                if self._at_end():
                    continue
                return False
            if self.sent_early and self.passes == 0 and (raw.topic, raw.log_ns) in self.sent_early:
                continue  # already sent by latched_first
            t = schedule_stamp(raw)
            if self.pass_first_ns is None:
                self.pass_first_ns = t
            t = max(t + self.shift_ns, self.last_t)  # never earlier than the one before: file order holds
            self.last_t = t
            self.buf.append((t, raw, self.gen))
            return True

    def fill(self, budget_s: float, ahead: int) -> None:
        """Read ahead for up to ``budget_s`` seconds or until ``ahead`` messages wait."""
        t_end = time.perf_counter() + budget_s
        while len(self.buf) < ahead and time.perf_counter() < t_end:
            if not self.read_one():
                break

    def peek(self) -> tuple[int, RawMessage, int] | None:
        """The next (schedule time ns, message, generation), None at the end."""
        if not self.buf and not self.read_one():
            return None
        return self.buf[0]


class _Pacer:
    """The bag's axis against the wall clock: bag time ``t`` (ns) is due at
    ``anchor_wall + (t - anchor_bag) / 1e9 / rate`` (clock seconds)."""

    def __init__(self, clock, rate: float) -> None:
        self.clock = clock
        self.rate = rate
        self.anchor_wall = 0.0
        self.anchor_bag: int | None = None  # None: not anchored (the next due message will be)

    def anchor(self, bag_ns: int) -> None:
        """Bag time ``bag_ns`` is now."""
        self.anchor_bag = bag_ns
        self.anchor_wall = self.clock()

    def bag_now(self) -> int:
        """The bag time (ns) it is now; only when anchored."""
        return self.anchor_bag + int((self.clock() - self.anchor_wall) * self.rate * 1e9)

    def due(self, t: int) -> float:
        """Clock time (s) bag time ``t`` (ns) is due."""
        return self.anchor_wall + (t - self.anchor_bag) / 1e9 / self.rate

    def set_rate(self, rate: float) -> None:
        """Change speed from now on: when anchored, re-anchored at the present bag time first."""
        if self.anchor_bag is not None:
            self.anchor(self.bag_now())
        self.rate = rate


class _Renumbering:
    """Sequence numbers that continue across loop passes and seeks, per (bag topic, sender).

    Within a generation (a pass, or what follows a seek) each stream keeps a constant offset;
    the first message of a new generation sets it so the stream goes on from the last number sent.
    """

    def __init__(self) -> None:
        self.last: dict[tuple[str, bytes], int] = {}
        self.offset: dict[tuple[str, bytes], int] = {}
        self.gen = 0

    def apply(self, topic: str, header: bytearray, gen: int) -> None:
        """Renumber the codec ``header`` of a message of bag ``topic`` in place."""
        key = (topic, header_sender(header))
        seq = header_seq(header)
        if gen != self.gen:
            self.offset = {}
            self.gen = gen
        off = self.offset.get(key)
        if off is None:
            off = self.offset[key] = (self.last[key] + 1 - seq) if key in self.last else 0
        if off:
            set_header_seq(header, seq + off)
        self.last[key] = seq + off


class _SendStats:
    """What was sent and how well: the count, lag behind schedule over the last LAG_WINDOW
    sends (s), and the achieved rate (bag seconds per clock second, over >= 0.5 s)."""

    def __init__(self) -> None:
        self.sent = 0
        self.lags = np.zeros(LAG_WINDOW)
        self.nlags = 0
        self.rate_mark: tuple[float, int] | None = None  # (clock s, bag ns) the rate is measured from
        self.achieved_rate = float("nan")
        np.percentile(self.lags[:2], [50, 99])  # numpy's first call costs ~15 ms: not while playing

    def restart_rate(self) -> None:
        """Measure the rate afresh (after a pause, seek or rate change)."""
        self.rate_mark = None

    def record(self, items: list[Outgoing], sent_at: float, playing: bool) -> None:
        for o in items:
            self.lags[self.nlags % LAG_WINDOW] = sent_at - o.due_s
            self.nlags += 1
            self.sent += 1
        if items and playing:
            t = items[-1].bag_ns
            if self.rate_mark is None:
                self.rate_mark = (sent_at, t)
            elif sent_at - self.rate_mark[0] > 0.5:
                self.achieved_rate = (t - self.rate_mark[1]) / 1e9 / (sent_at - self.rate_mark[0])
                self.rate_mark = (sent_at, t)

    def lags_s(self) -> np.ndarray:
        return self.lags[:min(self.nlags, LAG_WINDOW)].copy()

    def lag_ms(self) -> tuple[float, float, float]:
        n = min(self.nlags, LAG_WINDOW)
        if n == 0:
            return float("nan"), float("nan"), float("nan")
        lags = self.lags[:n] * 1e3
        return float(np.percentile(lags, 50)), float(np.percentile(lags, 99)), float(lags.max())


class Playback:
    """The schedule of one bag. Call `begin`, then repeatedly `take_due(now)` / `next_due()`.

    rate: playback speed (2.0 plays twice as fast). start_s / end_s: window in seconds from the
    bag's start. loop: start over at the end. remap: bag topic -> sent topic.

    The parts: `_Feed` reads ahead, `_Pacer` ties the bag's axis to the clock, `_Renumbering`
    keeps sequence numbers going, `_SendStats` counts; this class is the play/pause/seek/step
    state that drives them.
    """

    def __init__(self, reader: BagReader, *, topics: Iterable[str] | None = None, exclude: str | None = None,
                 rate: float = 1.0, start_s: float = 0.0, end_s: float | None = None, loop: bool = False,
                 remap: dict[str, str] | None = None, clock=time.monotonic) -> None:
        if not rate > 0:
            raise BagError(reader.path, f"rate must be positive, got {rate}")
        self.reader = reader
        self.summary = reader.summary()
        self.topics, self.skipped = select_topics(reader.topic_infos(), topics, exclude)
        if not self.topics:
            raise BagError(reader.path, "has no topic that can be played"
                           + (f" ({'; '.join(f'{k}: {v}' for k, v in self.skipped.items())})" if self.skipped else ""))
        self.remap = dict(remap or {})
        self.loop = loop
        self.clock = clock
        # Windows (start/end/seek) select on log time, the MCAP index; positions are reported on
        # the publish-stamp axis that drives the schedule. The two differ by the recorder's delay.
        log0 = self.summary.start_ns
        self.start_s = max(0.0, start_s)
        self.start_ns = log0 + int(max(0.0, start_s) * 1e9)
        self.end_ns = None if end_s is None else log0 + int(end_s * 1e9)
        if self.end_ns is not None and self.end_ns <= self.start_ns:
            raise BagError(reader.path, f"--end {end_s} s is not after --start {start_s} s")
        self.origin_ns, self.duration_s = self._origin_and_duration(end_s)
        self.state = "idle"
        self._pause_bag_ns: int | None = None  # where a paused playback stands
        self._last_sent_ns: int | None = None
        self._feed = _Feed(reader, sorted(self.topics), self.start_ns, self.end_ns, loop,
                           self._typical_period_ns())
        self._pacer = _Pacer(clock, float(rate))
        self._numbers = _Renumbering()
        self._stats = _SendStats()

    def _origin_and_duration(self, end_s: float | None) -> tuple[int, float]:
        """(the schedule stamp (ns) of the first message played, the window's length (s))."""
        names = sorted(self.topics)
        origin_ns, last_pub = self.reader.publish_span(names)
        first = next(iter(self.reader.messages(names)), None)
        if first is not None:
            origin_ns = schedule_stamp(first)
        return origin_ns, (end_s if end_s is not None else max(0.0, (last_pub - origin_ns) / 1e9))

    def _typical_period_ns(self) -> int:
        """Period (ns) of the busiest topic: the gap left between two loop passes."""
        busiest = max(self.topics, key=lambda t: self.topics[t].count)
        rate = self.summary.topics[busiest].rate_hz
        return int(1e9 / rate) if rate > 0 else 0

    # ----- what the parts hold ---------------------------------------------------------------
    @property
    def rate(self) -> float:
        return self._pacer.rate

    @property
    def loops(self) -> int:
        return self._feed.loops

    @property
    def sent(self) -> int:
        return self._stats.sent

    @property
    def achieved_rate(self) -> float:
        return self._stats.achieved_rate

    @property
    def _buf(self) -> deque[tuple[int, RawMessage, int]]:
        return self._feed.buf

    # ----- reading -----------------------------------------------------------------------------
    def _read_one(self) -> bool:
        """Move one message from the bag into the buffer; False at the end (after looping)."""
        return self._feed.read_one()

    def fill(self, budget_s: float = 0.002, ahead: int = 2048) -> None:
        """Read ahead for up to ``budget_s`` (call when idle, so that chunk decoding never delays a send)."""
        self._feed.fill(budget_s, ahead)

    # ----- control -----------------------------------------------------------------------------
    def latched_first(self) -> list[Outgoing]:
        """The value of each latched topic at the start position, to send before anything else."""
        latched = [t for t, info in self.topics.items() if info.latched]
        if not latched:
            return []
        # a latched value recorded just after the start (a recorder reads its topics' sockets in turn)
        # is the state at the start all the same
        horizon = self.start_ns + LATCHED_GRACE_NS
        best: dict[str, RawMessage] = {}
        for raw in self.reader.messages(latched, None, None):
            if raw.log_ns <= horizon or raw.topic not in best:
                best[raw.topic] = raw
            if raw.log_ns > horizon and len(best) == len(latched):
                break
        out = []
        for raw in best.values():
            if raw.log_ns <= horizon:
                out.append(self._outgoing(raw.publish_ns, raw, self.clock(), self._feed.gen))
                self._feed.sent_early.add((raw.topic, raw.log_ns))
        return out

    def begin(self, paused: bool = False) -> None:
        self._feed.open(self.start_ns)
        self._pacer.anchor_bag = None
        self.state = "paused" if paused else "playing"
        if paused:
            first = self._feed.peek()
            self._pause_bag_ns = first[0] if first else self.start_ns

    def pause(self) -> None:
        if self.state == "playing":
            self._pause_bag_ns = self._bag_now()
            self.state = "paused"

    def resume(self) -> None:
        if self.state == "paused":
            self._pacer.anchor(self._pause_bag_ns)
            self.state = "playing"
            self._stats.restart_rate()

    def toggle(self) -> None:
        self.resume() if self.state == "paused" else self.pause()

    def set_rate(self, rate: float) -> None:
        if not rate > 0:
            raise ValueError(f"rate must be positive, got {rate}")
        if self.state == "playing":
            self._pacer.set_rate(float(rate))
        else:
            self._pacer.rate = float(rate)
        self._stats.restart_rate()

    def seek(self, position_s: float) -> None:
        """Jump to ``position_s`` from the bag's start; keeps playing or paused. A position past the
        end is the end (the last message; a looping player then starts over)."""
        last_ns = self.summary.end_ns if self.end_ns is None else self.end_ns - 1
        target = min(self.summary.start_ns + int(min(max(0.0, position_s), 1e7) * 1e9), last_ns)
        self._feed.restart_at(max(target, self.start_ns))
        first = self._feed.peek()
        t0 = first[0] if first else target
        if self.state == "playing":
            self._pacer.anchor(t0)
        else:
            self._pause_bag_ns = t0
        self._stats.restart_rate()
        if first is None:
            self.state = "finished" if not self.loop else self.state

    def step(self) -> list[Outgoing]:
        """While paused: the next message and every following one with the same capture stamp."""
        if self.state != "paused":
            return []
        first = self._feed.peek()
        if first is None:
            return []
        now = self.clock()
        out = [self._pop(now)]
        cap = header_capture_ns(out[0].frames[1])
        while True:
            nxt = self._feed.peek()
            if nxt is None:
                break
            if header_capture_ns(header_of(nxt[1].data)) != cap:
                break
            out.append(self._pop(now))
        self._pause_bag_ns = out[-1].bag_ns
        return out

    # ----- timing -----------------------------------------------------------------------------
    def _bag_now(self) -> int:
        if self._pacer.anchor_bag is None:
            return self._last_sent_ns or self.start_ns
        return self._pacer.bag_now()

    def next_due(self) -> float | None:
        """Monotonic time the next message is due, None when paused or finished."""
        if self.state != "playing":
            return None
        nxt = self._feed.peek()
        if nxt is None:
            self.state = "finished"
            return None
        if self._pacer.anchor_bag is None:
            self._pacer.anchor(nxt[0])
        return self._pacer.due(nxt[0])

    def take_due(self, now: float | None = None) -> list[Outgoing]:
        """Every message due at ``now`` (never one that is not yet due)."""
        out: list[Outgoing] = []
        while True:
            due = self.next_due()
            now = self.clock() if now is None else now
            if due is None or due > now:
                return out
            out.append(self._pop(now, due))
            now = None

    def _pop(self, now: float, due: float | None = None) -> Outgoing:
        t, raw, gen = self._feed.buf.popleft()
        o = self._outgoing(t, raw, now if due is None else due, gen)
        self._last_sent_ns = t
        return o

    def _outgoing(self, t: int, raw: RawMessage, due: float, gen: int = 0) -> Outgoing:
        """``raw`` ready to send: on its remapped topic, renumbered, with a writable header."""
        topic = self.remap.get(raw.topic, raw.topic)
        frames = raw.frames(topic)
        header = bytearray(frames[1])
        self._numbers.apply(raw.topic, header, gen)
        frames[1] = header
        return Outgoing(topic, frames, header_latched(header), t, due)

    def record_sent(self, items: list[Outgoing], sent_at: float) -> None:
        """Account messages the caller has just sent (lag statistics, achieved rate)."""
        self._stats.record(items, sent_at, self.state == "playing")

    # ----- reporting -----------------------------------------------------------------------------
    @property
    def position_s(self) -> float:
        t = self._last_sent_ns if self.state != "paused" else self._pause_bag_ns
        if t is None:
            return self.start_s
        return max(0.0, (t - self._feed.shift_ns - self.origin_ns) / 1e9)

    def lag_ms(self) -> tuple[float, float, float]:
        """Send lag behind schedule over the recent window: p50, p99, max, ms (NaN before any)."""
        return self._stats.lag_ms()

    def lags_s(self) -> np.ndarray:
        """The recent send lags behind schedule, s, oldest first until the window wraps."""
        return self._stats.lags_s()
