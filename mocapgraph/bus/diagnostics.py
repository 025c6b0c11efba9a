"""Diagnostics messages built from edge records (a node's inputs, a source's device streams)."""
from __future__ import annotations

import math
import os
import resource
from dataclasses import dataclass
from typing import Any, Iterable

from ..messages import Diagnostics
from .stats import InputStats

DIAGNOSTICS_TOPIC = "diagnostics"
DIAGNOSTICS_PERIOD_S = 1.0


@dataclass(frozen=True)
class EdgeRecord:
    """One incoming stream's figures: rate (Hz), latency median/max (ms), counts."""

    topic: str
    sender: str = "device"
    rate_hz: float = 0.0
    latency_ms: float = math.nan
    latency_max_ms: float = math.nan
    received: int = 0
    gaps: int = 0
    rejected: int = 0
    anomalies: int = 0


@dataclass(frozen=True)
class ClockRecord:
    """One clock a node maps onto its own (a device's, another machine's): offset, drift, jitter."""

    name: str
    offset_ms: float = math.nan
    drift_ppm: float = math.nan
    jitter_ms: float = math.nan
    resets: int = 0


def device_clock(name: str, clock: Any) -> list[ClockRecord]:
    """A device clock followed by a :class:`~mocapgraph.messages.clock_sync.ClockSync` as its record
    (offset ms, drift ppm, jitter ms, resets), or none before its first frame."""
    c = clock.stats()
    return [ClockRecord(name, c.offset_ns / 1e6, c.drift_ppm, c.jitter_ms, c.resets)] if c.samples else []


UNEXPECTED_SENDER = "(unexpected)"


def input_edge_records(topic: str, stats: InputStats) -> list[EdgeRecord]:
    """The edges of one input; frames rejected before any sender was known count on sender '?',
    frames of senders the wiring does not name on one record, sender UNEXPECTED_SENDER."""
    edges = list(stats.edges.values())
    out = []
    if not edges and stats.rejected:
        out.append(EdgeRecord(topic, "?", rejected=stats.rejected))
    for i, e in enumerate(edges):
        p50, pmax = e.latency_ms()
        out.append(EdgeRecord(e.topic, e.sender, e.rate_hz(), p50, pmax, e.received, e.gaps,
                              stats.rejected if i == 0 else 0, e.anomalies + e.restarts))
    if stats.unexpected:
        out.append(EdgeRecord(topic, UNEXPECTED_SENDER, rejected=stats.unexpected))
    return out


def build_diagnostics(node: str, uptime_s: float, edges: Iterable[EdgeRecord],
                      outputs: Iterable[tuple[str, int]], clocks: Iterable[ClockRecord] = ()) -> Diagnostics:
    """The Diagnostics message of this process: edges, (output topic, messages sent), CPU time,
    the clocks it follows."""
    edges = list(edges)
    outputs = list(outputs)
    clocks = list(clocks)
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return Diagnostics(
        node=node, pid=os.getpid(), uptime_s=uptime_s, cpu_s=ru.ru_utime + ru.ru_stime,
        edge_topics=[e.topic for e in edges], edge_senders=[e.sender for e in edges],
        edge_rate_hz=[float(e.rate_hz) for e in edges], edge_latency_ms=[float(e.latency_ms) for e in edges],
        edge_latency_max_ms=[float(e.latency_max_ms) for e in edges],
        edge_received=[int(e.received) for e in edges], edge_gaps=[int(e.gaps) for e in edges],
        edge_rejected=[int(e.rejected) for e in edges], edge_anomalies=[int(e.anomalies) for e in edges],
        output_topics=[t for t, _ in outputs], output_sent=[n for _, n in outputs],
        clock_names=[c.name for c in clocks], clock_offset_ms=[float(c.offset_ms) for c in clocks],
        clock_drift_ppm=[float(c.drift_ppm) for c in clocks], clock_jitter_ms=[float(c.jitter_ms) for c in clocks],
        clock_resets=[int(c.resets) for c in clocks],
    )
