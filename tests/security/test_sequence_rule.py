"""The sequence rule and the bounded edge table, on their own (no processes)."""
from __future__ import annotations

from mocapgraph.bus.stats import ANY_SENDER, MAX_FREE_EDGES, InputStats
from mocapgraph.messages.sequence import ANOMALY, DUPLICATE, RESTART, sequence_gap


def test_forged_jumps_are_anomalies_and_the_real_stream_resynchronises() -> None:
    assert sequence_gap(100, 101) == 0 and sequence_gap(100, 105) == 4
    assert sequence_gap(100, 100) == DUPLICATE and sequence_gap(100, 98) == DUPLICATE
    assert sequence_gap(100, 1) == RESTART
    assert sequence_gap(100, 1 << 63) == ANOMALY
    assert sequence_gap(1 << 63, 101) == ANOMALY  # back from the forged number: resync, not a duplicate
    stats = InputStats(["reader"])
    e = stats.edge("markers", "reader")
    for s in range(1, 101):
        assert e.accept(s, s, s)
    assert e.accept(1 << 63, 0, 0)
    assert all(e.accept(s, s, s) for s in range(101, 200)), "real frames after a forged one are delivered"
    assert e.gaps == 0 and e.anomalies == 2 and e.duplicates == 0


def test_only_named_senders_get_edges() -> None:
    named = InputStats(["reader"])
    assert named.edge("m", "reader") is not None
    assert all(named.edge("m", f"junk{i}") is None for i in range(1000))
    assert len(named.edges) == 1 and named.unexpected == 1000
    free = InputStats(["reader", ANY_SENDER])
    for i in range(1000):
        free.edge("m", f"junk{i}")
    assert len(free.edges) == MAX_FREE_EDGES and free.unexpected == 1000 - MAX_FREE_EDGES
    assert free.edge("m", "reader") is not None  # a named sender always gets its edge
