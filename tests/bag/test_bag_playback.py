"""The playback schedule (no sockets): order, timing at any rate, pause/step/seek, loop, latched first."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from bagutil import write_bag
from mocapgraph.bag.errors import BagError
from mocapgraph.bag.player import Playback, parse_remaps
from mocapgraph.bag.reader import BagReader
from mocapgraph.messages import decode, decode_envelope


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def run(pb: Playback, clock: FakeClock, step_s: float = 0.0005, limit: int = 100000) -> list:
    """Drive the schedule with a fake clock; returns (send time, outgoing) in send order."""
    sent = []
    for _ in range(limit):
        if pb.state == "finished":
            break
        for o in pb.take_due():
            assert o.due_s <= clock.t + 1e-12, "a message went out before it was due"
            sent.append((clock.t, o))
        due = pb.next_due()
        if due is None:
            break
        clock.t = max(clock.t + step_s, due) if due > clock.t else clock.t + step_s
    return sent


@pytest.mark.parametrize("rate", [1.0, 4.0, 0.5])
def test_relative_timing_and_order_at_any_rate(tmp_path, rate):
    path = write_bag(tmp_path / "a.mcap", frames=40, period_ns=10_000_000)
    clock = FakeClock()
    with BagReader(path) as r:
        pb = Playback(r, rate=rate, clock=clock)
        pb.begin()
        sent = run(pb, clock, step_s=1e-5)
    markers = [(t, o) for t, o in sent if o.topic == "markers"]
    assert len(markers) == 40
    seqs = [decode_envelope(o.frames).seq for _, o in markers]
    assert seqs == list(range(1, 41))
    t = np.array([t for t, _ in markers])
    expected = np.arange(40) * 0.010 / rate
    np.testing.assert_allclose(t - t[0], expected, atol=2e-5)


def test_frames_are_the_stored_bytes_but_the_publish_stamp(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=5)
    clock = FakeClock()
    with BagReader(path) as r:
        stored = [raw.frames() for raw in r.messages()]
        pb = Playback(r, clock=clock)
        pb.begin()
        sent = [o for _, o in run(pb, clock)]
    assert len(sent) == len(stored) == 6
    for o, s in zip(sent, stored):
        assert [bytes(f) for f in o.frames[2:]] == [bytes(f) for f in s[2:]]
        assert bytes(o.frames[0]) == bytes(s[0])
        assert bytes(o.frames[1][:26]) == bytes(s[1][:26])  # magic .. seq, capture stamp
        assert bytes(o.frames[1][34:]) == bytes(s[1][34:])  # type and sender names
        env, msg = decode(o.frames)
        assert env.capture_ns == decode_envelope(s).capture_ns


def test_pause_step_resume_and_seek(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=30, period_ns=10_000_000)
    clock = FakeClock()
    with BagReader(path) as r:
        pb = Playback(r, clock=clock)
        pb.begin(paused=True)
        assert pb.take_due() == [] and pb.next_due() is None
        stepped = pb.step()  # layout shares the first frame's capture stamp
        assert [o.topic for o in stepped] == ["marker_layout", "markers"]
        assert [o.topic for o in pb.step()] == ["markers"]
        assert pb.position_s == pytest.approx(0.010)
        pb.resume()
        clock.t += 0.0101
        got = pb.take_due()
        assert [decode_envelope(o.frames).seq for o in got] == [3]
        pb.pause()
        clock.t += 5.0  # nothing goes out while paused, and time paused is not made up for
        assert pb.take_due() == []
        pb.resume()
        assert pb.take_due() == []
        clock.t += 0.0101
        assert [decode_envelope(o.frames).seq for o in pb.take_due()] == [4]
        # seek back: the replayed frame_numbers restart but sequence numbers continue (no receiver drops)
        pb.seek(0.05)
        clock.t += 0.001
        o = pb.take_due()[0]
        env, msg = decode(o.frames)
        assert msg.frame_number == 5 and env.seq == 5
        pb.seek(0.0)
        out = run(pb, clock)
        envs = [decode(o.frames) for _, o in out if o.topic == "markers"]
        assert envs[0][1].frame_number == 0 and envs[0][0].seq == 6
        assert [e.seq for e, _ in envs] == list(range(6, 36))


def test_loop_keeps_sequence_continuous_and_time_growing(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=10, period_ns=10_000_000, seq0=500)
    clock = FakeClock()
    with BagReader(path) as r:
        pb = Playback(r, loop=True, clock=clock)
        pb.begin()
        sent = []
        while len(sent) < 35:
            sent += [(clock.t, o) for o in pb.take_due() if o.topic == "markers"]
            pb.fill(budget_s=1.0, ahead=25)  # read ahead across the loop seam, as the node does
            clock.t += 0.001
    seqs = [decode_envelope(o.frames).seq for _, o in sent]
    assert seqs == list(range(500, 535))
    t = np.array([t for t, _ in sent])
    assert np.all(np.diff(t) > 0.0085)  # the seam between passes keeps one frame interval
    assert pb.loops >= 3


def test_start_sends_latched_state_first_and_remap(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=50, period_ns=10_000_000)
    clock = FakeClock()
    with BagReader(path) as r:
        pb = Playback(r, start_s=0.2, end_s=0.3, remap=parse_remaps(["markers:=raw"]), clock=clock)
        first = pb.latched_first()
        assert [o.topic for o in first] == ["marker_layout"] and first[0].latched
        pb.begin()
        out = [o for _, o in run(pb, clock)]
    assert {o.topic for o in out} == {"raw"}
    nums = [decode(o.frames)[1].frame_number for o in out]
    assert nums == list(range(20, 30))
    assert bytes(out[0].frames[0]) == b"raw\0"


def test_bad_arguments(tmp_path):
    path = write_bag(tmp_path / "a.mcap", frames=5)
    with BagReader(path) as r:
        with pytest.raises(BagError, match="no topic 'nope'"):
            Playback(r, topics=["nope"])
        with pytest.raises(BagError, match="not after"):
            Playback(r, start_s=2.0, end_s=1.0)
    with pytest.raises(ValueError, match="old:=new"):
        parse_remaps(["markers"])
