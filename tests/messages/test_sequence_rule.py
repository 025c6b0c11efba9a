"""The sequence rule and the bounded edge table, on their own (no processes)."""
from __future__ import annotations

from mocapgraph.bus.stats import ANY_SENDER, MAX_FREE_EDGES, EdgeStats, InputStats
from mocapgraph.messages.sequence import ANOMALY, DUPLICATE, DUPLICATE_WINDOW, RESTART, sequence_gap


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


def _edge_at(last: int, stream: int = 7) -> EdgeStats:
    """An edge whose stream ``stream`` has delivered 1..last, stamps = numbers."""
    e = InputStats(["solver"]).edge("actor_pose", "solver")
    assert all(e.accept(s, s, s, stream) for s in range(1, last + 1))
    return e


def test_the_duplicate_window_edge_a_frame_exactly_the_window_back_and_one_further() -> None:
    last = DUPLICATE_WINDOW + 100
    # exactly the window back: a suspected duplicate, dropped (its first time)
    e = _edge_at(last)
    assert not e.accept(last - DUPLICATE_WINDOW, 10**9, 10**9, 7)
    assert (e.duplicates, e.anomalies) == (1, 0)
    assert e.accept(last + 1, last + 1, last + 1, 7) and e.gaps == 0, "the stream goes on above it, no loss"
    # one further: beyond belief as a resend, so the edge resynchronises to it at once
    e = _edge_at(last)
    assert e.accept(last - DUPLICATE_WINDOW - 1, 10**9, 10**9, 7)
    assert (e.duplicates, e.anomalies, e.last_seq) == (0, 1, last - DUPLICATE_WINDOW - 1)
    assert e.accept(last - DUPLICATE_WINDOW, 10**9 + 1, 10**9 + 1, 7) and e.gaps == 0
    # the stateless rule says the same at the edge
    assert sequence_gap(last, last - DUPLICATE_WINDOW) == DUPLICATE
    assert sequence_gap(last, last - DUPLICATE_WINDOW - 1) == ANOMALY


def test_a_forged_frame_above_the_real_stream_costs_it_one_frame_and_no_loss() -> None:
    e = _edge_at(100)
    assert e.accept(100 + 4000, 0, 0, 7)   # forged: the real sender's name and stream id, real+4000
    delivered = [s for s in range(101, 200) if e.accept(s, s, s, 7)]
    assert delivered == list(range(102, 200)), "one real frame dropped as a suspected duplicate, then the stream"
    assert e.gaps == 0, "the forged jump's 3999 'lost' frames are taken back"
    assert (e.duplicates, e.anomalies) == (1, 1)
    # the forged frame sent again after every real one: each copy costs at most one real frame
    e = _edge_at(100)
    forged = (100 + 4000, 0, 0, 7)
    got = []
    for s in range(101, 201):
        e.accept(*forged)
        got.append(e.accept(s, s, s, 7))
    assert sum(got) == 50 and not any(a == b == False for a, b in zip(got, got[1:])), got


def test_a_new_stream_id_is_a_new_stream_from_any_number() -> None:
    e = _edge_at(5000, stream=7)
    # a respawned sender: numbers from 1, but its first frames missed (joined at 3): all delivered
    assert all(e.accept(s, 10**6 + s, 0, 8) for s in range(3, 200))
    assert (e.restarts, e.duplicates, e.gaps, e.anomalies) == (1, 0, 0, 0)
    assert e.accept(201, 10**6 + 201, 0, 8) and e.gaps == 1   # loss within the new stream is counted
    # frames of the old process still queued after the new one's: each side delivered
    assert e.accept(5001, 5001, 0, 7) and e.accept(202, 10**6 + 202, 0, 8)
    assert e.restarts == 3 and e.duplicates == 0


def test_latched_resends_are_dropped_however_often_they_come() -> None:
    e = _edge_at(1)
    assert not any(e.accept(1, 1, 1, 7) for _ in range(100))   # the same number and stamp: a resend
    assert e.duplicates == 100 and e.received == 1
    assert e.accept(1, 99, 99, 7) and e.restarts == 1   # the same number, a new stamp: a restarted sender's value
