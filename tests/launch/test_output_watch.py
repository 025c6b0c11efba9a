"""The launcher's output watch on the diagnostics a node really sends: a steady output that stops while
its inputs keep receiving is stalled, whatever phase of the 1 Hz reports it stopped in."""
from __future__ import annotations

from mocapgraph.bus.diagnostics import EdgeRecord, build_diagnostics
from mocapgraph.launch.liveness import STALL_S, OutputWatch


def _report(received: int, sent: int):
    """The solver's diagnostics: markers received so far, poses sent so far."""
    return build_diagnostics("solver", 1.0, [EdgeRecord("markers", "reader", received=received)],
                             [("actor_pose", sent)])


def _run(sends_per_report: list[int], inputs_per_report: int = 30) -> tuple[float | None, list]:
    """Feed one report a second; returns (when the stall was reported, s, or None; the lines)."""
    watch = OutputWatch({"solver": {"actor_pose"}})
    received = sent = 0
    for i, n in enumerate(sends_per_report):
        received += inputs_per_report
        sent += n
        stalled, _ = watch.heard("solver", _report(received, sent), float(i))
        if stalled:
            return float(i), stalled
    return None, []


def test_a_30_hz_output_that_stops_just_after_a_report_is_stalled() -> None:
    # 30 poses a second for 6 s, then 1 pose in the partial second in which the solver refused its layout
    at, stalled = _run([30] * 6 + [1] + [0] * 8)
    assert stalled and stalled[0][0] == "actor_pose", "the partial last interval unwatched a steady output"
    assert at - 6.0 >= STALL_S and at - 6.0 <= STALL_S + 1.0, at


def test_a_stream_that_stops_on_a_report_boundary_is_stalled_too() -> None:
    at, stalled = _run([30] * 6 + [0] * 8)
    assert stalled and at - 5.0 >= STALL_S


def test_an_output_that_really_slowed_down_is_not_called_stalled() -> None:
    # 30 Hz, then one message a second for good (a status-like stream): never a stall
    at, _ = _run([30] * 6 + [1] * 12)
    assert at is None


def test_an_output_that_never_flowed_steadily_is_not_watched() -> None:
    at, _ = _run([1] * 6 + [0] * 8)
    assert at is None


def test_an_idle_node_whose_inputs_stopped_too_is_not_stalled() -> None:
    at, _ = _run([30] * 6 + [0] * 8, inputs_per_report=0)
    assert at is None
