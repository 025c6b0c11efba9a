"""The device clock estimator on synthetic (device time, arrival time) pairs whose true capture
times are known: offset, drift, jitter, resets and stalls, over ten minutes of simulated time."""
from __future__ import annotations

import numpy as np
import pytest

from mocapgraph.messages.clock_sync import ClockSync, line_under, lower_hull

T0 = 1_800_000_000_000_000_000          # our clock's epoch ns, as time.time_ns() reads in 2027


def stream(rate: float, seconds: float, drift_ppm: float, max_delay_ms: float = 20.0, seed: int = 0,
           dev0_ns: int = 5_000_000_000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A device pacing frames by its own clock (``drift_ppm`` fast against ours): its stamps, the
    frames' true capture times on our clock, and arrivals after a uniform 0..max_delay_ms delay."""
    k = np.arange(int(rate * seconds))
    dev = dev0_ns + np.round(k * 1e9 / rate).astype(np.int64)
    true = T0 + np.round(k * 1e9 / rate / (1 + drift_ppm * 1e-6)).astype(np.int64)
    delay = np.round(np.random.default_rng(seed).uniform(0, max_delay_ms * 1e6, k.size)).astype(np.int64)
    return dev, true, true + delay


def run(sync: ClockSync, dev: np.ndarray, arrival: np.ndarray, latency=None) -> np.ndarray:
    lat = np.zeros_like(dev) if latency is None else latency
    return np.array([sync.update(int(d), int(a), int(la)) for d, a, la in zip(dev, arrival, lat)])


@pytest.mark.parametrize("rate,drift_ppm,seed", [(240.0, 100.0, 1), (120.0, -100.0, 2)])
def test_within_1ms_after_2s_and_for_10_minutes_with_20ms_delay_and_100ppm_drift(rate, drift_ppm, seed) -> None:
    dev, true, arrival = stream(rate, 600.0, drift_ppm, seed=seed)
    sync = ClockSync()
    cap = run(sync, dev, arrival)
    err_ms = (cap - true) / 1e6
    t = np.arange(dev.size) / rate
    assert np.abs(err_ms[t >= 2.0]).max() < 1.0
    assert np.abs(err_ms[t >= 60.0]).max() < 0.2                         # settled: a fraction of that
    assert np.all(cap <= arrival)                                         # never stamped after it arrived
    # what the first-frame offset gave: that frame's delay baked in, the drift left to grow (60 ms in 10 min)
    fixed = dev + (arrival[0] - dev[0])
    assert np.abs((fixed - true)[t >= 2.0]).max() / 1e6 > 50
    st = sync.stats()
    assert st.drift_ppm == pytest.approx(drift_ppm, abs=3.0)
    assert st.jitter_ms == pytest.approx(20 / np.sqrt(12), rel=0.2)       # std of U(0, 20 ms)
    assert st.delay_ms == pytest.approx(10.0, rel=0.2)
    assert st.offset_ns == pytest.approx(int(true[-1] - dev[-1]), abs=200_000)
    assert st.resets == 0 and st.samples == dev.size
    assert st.points <= 120 and 59.0 <= st.span_s <= 60.0                 # bounded: 60 s of 0.5 s windows


def test_device_restart_and_clock_jump_reseed_once_and_resettle() -> None:
    rate = 200.0
    dev, true, arrival = stream(rate, 30.0, 50.0, seed=3)
    dev = dev.copy()
    dev[2000:] -= dev[2000] - 1000                  # restarted at frame 2000: its clock from ~0 again
    dev[4000:] += 3_600_000_000_000                 # and at frame 4000 it jumps an hour ahead
    sync = ClockSync()
    cap = run(sync, dev, arrival)
    err_ms = np.abs(cap - true) / 1e6
    assert sync.stats().resets == 2
    t = np.arange(dev.size) / rate
    for start in (0.0, 10.0, 20.0):                 # each part settles as a fresh start does
        part = (t >= start + 2.0) & (t < start + 10.0)
        assert err_ms[part].max() < 1.0, start
    assert np.all(cap <= arrival)


def test_network_stall_is_not_a_reset_but_a_stopped_clock_is() -> None:
    rate = 100.0
    dev, true, arrival = stream(rate, 20.0, 0.0, seed=4)
    arrival = arrival.copy()
    stall = (arrival >= T0 + 8_000_000_000) & (arrival < T0 + 8_800_000_000)
    arrival[stall] = T0 + 8_800_000_000             # 0.8 s without packets, then the backlog at once
    sync = ClockSync()
    cap = run(sync, dev, arrival)
    assert sync.stats().resets == 0
    assert np.abs((cap - true)[200:]).max() / 1e6 < 1.0           # from 2 s on, the late frames too
    assert np.abs((cap - true)[stall]).max() / 1e6 < 1.0

    # a device whose clock stood still while it sent nothing for 3 s, then went on from where it
    # stopped: its frames now arrive 3 s after their stamps say
    idx = np.r_[0:1000, 1300:dev.size]
    frozen = ClockSync()
    cap2 = run(frozen, dev[:idx.size], arrival[idx])
    err2_ms = (cap2 - true[idx]) / 1e6
    assert frozen.stats().resets == 1               # after confirm_s of frames 3 s late, not at once
    assert np.all(err2_ms[1000:1095] < -2900)       # that second: the old line, as in a stall
    assert np.abs(err2_ms[1300:]).max() < 1.0       # then re-seeded and settled


def test_latency_maps_the_stamp_back_to_mid_exposure() -> None:
    rate = 240.0
    dev, true, arrival = stream(rate, 10.0, 30.0, seed=5)
    # the device stamps frames when it sends them, 2-6 ms after mid-exposure, and says how long
    lat = np.round(np.random.default_rng(6).uniform(2e6, 6e6, dev.size)).astype(np.int64)
    sent_dev, sent_true = dev + lat, true + lat
    arrival = sent_true + (arrival - true)
    cap = run(ClockSync(), sent_dev, arrival, lat)
    t = np.arange(dev.size) / rate
    assert np.abs((cap - true)[t >= 2.0]).max() / 1e6 < 1.0


def test_forget_starts_again_without_a_reset_and_stats_before_any_sample() -> None:
    sync = ClockSync()
    st = sync.stats()
    assert st.samples == 0 and np.isnan(st.drift_ppm) and np.isnan(st.jitter_ms)
    assert sync.update(1000, T0) == T0                          # the first frame: its arrival
    sync.update(2000, T0 + 500)
    sync.forget()
    assert sync.update(10, T0 + 10**9) == T0 + 10**9            # anchored again, not a reset
    assert sync.stats().resets == 0 and sync.stats().samples == 3


def test_the_line_under_points_is_the_hull_edge_over_their_mean() -> None:
    xs = [0.0, 1.0, 2.0, 3.0, 4.0]
    ys = [5.0, 1.0, 3.0, 2.0, 9.0]
    assert lower_hull(xs, ys) == [0, 1, 3, 4]
    a, b = line_under(xs, ys)                                   # mean x = 2: the edge (1,1)-(3,2)
    assert (a, b) == pytest.approx((0.5, 0.5))
    assert all(y >= a + b * x - 1e-12 for x, y in zip(xs, ys))
