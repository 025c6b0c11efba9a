"""The zero-lag marker low-pass: its cutoff choice, ends, gaps and noise figure against known signals."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, filtfilt

from mocapgraph.kinematics.solving.lowpass import (MIN_FRAMES, filter_columns, gcv_cutoff, lowpass_markers,
                                                   noise_gain)

RATE = 120.0


def _movement(rng: np.random.Generator, frames: int, markers: int) -> np.ndarray:
    """float[T,M,3] smooth paths (m): a few random sines per coordinate, 0.3-4 Hz, 2-20 cm."""
    t = np.arange(frames)[:, None, None, None] / RATE
    f = rng.uniform(0.3, 4.0, size=(1, markers, 3, 4))
    amp = rng.uniform(0.02, 0.2, size=(1, markers, 3, 4))
    ph = rng.uniform(0, 2 * np.pi, size=(1, markers, 3, 4))
    return (amp * np.sin(2 * np.pi * f * t + ph)).sum(-1) + rng.uniform(-1, 1, size=(1, markers, 3))


def test_cross_validated_cutoff_is_near_the_best_one_and_about_halves_the_noise():
    # Seeds and signals no setting was chosen on; the best cutoff is found by trying every one
    # against the truth, which the filter never sees.
    for seed in (11, 12, 13):
        rng = np.random.default_rng(seed)
        true = _movement(rng, 600, 6)
        noisy = true + rng.normal(scale=0.001, size=true.shape)
        out, rep = lowpass_markers(noisy, RATE)
        rms = np.sqrt(np.mean((out - true) ** 2))
        grid = np.arange(2.0, 40.0, 1.0)
        best = min(np.sqrt(np.mean((filter_columns(noisy.reshape(600, -1), RATE, f).reshape(true.shape) - true) ** 2))
                   for f in grid)
        print(f"seed {seed}: cutoff {rep.cutoff_hz} Hz, rms {1e3 * rms:.3f} mm (raw 1.000, best cutoff {1e3 * best:.3f})")
        assert rms <= 0.55e-3 and rms <= 1.15 * best


def test_a_straight_line_passes_unchanged_to_its_ends():
    # The ends are reflected about a fitted line, so uniform motion is not bent at either end
    # (a plain odd reflection would pin the output to the first, noisy, sample).
    t = np.arange(200)[:, None] / RATE
    line = np.concatenate([0.3 + 1.5 * t, -0.2 * t, 1.0 + 0.0 * t], axis=1)
    assert np.abs(filter_columns(line, RATE, 6.0) - line).max() < 1e-9


def test_the_noise_gain_is_what_white_noise_shows():
    rng = np.random.default_rng(5)
    x = rng.normal(size=(40000, 4))
    for fc in (1.0, 6.0, 20.0):
        measured = filter_columns(x, RATE, fc)[2000:-2000].std() / x.std()
        assert noise_gain(RATE, fc) == pytest.approx(measured, rel=0.05)


def test_the_cutoff_is_the_pair_s_minus_3_db_point():
    # Two passes of a 2nd-order Butterworth: their combined gain at the stated cutoff is 1/sqrt(2).
    t = np.arange(4000) / RATE
    for fc in (3.0, 10.0):
        sine = np.sin(2 * np.pi * fc * t)[:, None]
        gain = filter_columns(sine, RATE, fc)[500:-500].std() / sine[500:-500].std()
        assert gain == pytest.approx(2 ** -0.5, abs=0.03)


def test_gaps_stay_gaps_and_do_not_spoil_the_rest():
    rng = np.random.default_rng(21)
    true = _movement(rng, 480, 3)
    noisy = true + rng.normal(scale=0.001, size=true.shape)
    noisy[100:130, 1] = np.nan      # a 0.25 s gap in one marker
    noisy[:, 2] = np.nan            # a marker never seen
    out, rep = lowpass_markers(noisy, RATE)
    assert np.isnan(out[100:130, 1]).all() and np.isnan(out[:, 2]).all()
    assert np.isfinite(out[:, 0]).all() and np.isfinite(np.delete(out[:, 1], np.s_[100:130], axis=0)).all()
    rms = lambda e: float(np.sqrt(np.nanmean(e ** 2)))  # noqa: E731
    beside = np.r_[85:100, 130:145]                       # the 15 frames either side of the gap
    print(f"rms mm: all {1e3 * rms(out[:, :2] - true[:, :2]):.3f}, beside the gap {1e3 * rms(out[beside, 1] - true[beside, 1]):.3f} "
          f"(raw {1e3 * rms(noisy[beside, 1] - true[beside, 1]):.3f})")
    assert rms(out[:, :2] - true[:, :2]) < 0.0006
    # Beside the gap the runs end, where a filter can only lean on one side: no worse than raw.
    assert rms(out[beside, 1] - true[beside, 1]) < rms(noisy[beside, 1] - true[beside, 1])


def test_short_or_empty_trials_are_left_raw_and_a_bad_cutoff_is_refused():
    x = np.random.default_rng(0).normal(size=(MIN_FRAMES - 1, 2, 3))
    out, rep = lowpass_markers(x, RATE)
    assert rep.cutoff_hz is None and rep.noise_gain == 1.0 and np.array_equal(out, x)
    out, rep = lowpass_markers(np.full((50, 2, 3), np.nan), RATE)
    assert rep.cutoff_hz is None and np.isnan(out).all()
    for bad in (0.0, 60.0, -3.0):
        with pytest.raises(ValueError, match="between 0 and half the rate"):
            lowpass_markers(np.zeros((50, 2, 3)), RATE, bad)


def test_filter_matches_scipy_filtfilt_away_from_the_ends():
    # The padding is ours; the filter itself is scipy's, cutoff corrected by 1 / 0.802 per pass.
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=(1000, 3)), axis=0)
    b, a = butter(2, 8.0 / 0.802 / (RATE / 2))
    assert np.allclose(filter_columns(x, RATE, 8.0)[200:-200], filtfilt(b, a, x, axis=0)[200:-200], atol=1e-6)
    assert gcv_cutoff(x[:, :1], RATE) >= 1.0


def test_the_live_fixed_lag_filter_gives_each_frame_late_with_its_tag_and_the_batch_figure():
    from mocapgraph.kinematics.solving.lowpass import FixedLagLowpass

    rng = np.random.default_rng(31)
    true = _movement(rng, 720, 4)
    noisy = true + rng.normal(scale=0.001, size=true.shape)
    noisy[300:310, 2] = np.nan                       # a short occlusion of one marker
    lp = FixedLagLowpass(4, RATE, 10.0, 12)
    got = [r for i, x in enumerate(noisy) if (r := lp.push(x, i)) is not None]
    tags = np.array([t for _, t in got])
    out = np.array([x for x, _ in got])
    assert np.array_equal(tags, np.arange(720 - 12))          # every frame, in order, 12 late
    batch = filter_columns(noisy[:, :2].reshape(720, -1), RATE, 10.0).reshape(720, 2, 3)
    rms = lambda e: float(np.sqrt(np.nanmean(e ** 2)))  # noqa: E731
    live, full = rms(out[100:600, :2] - true[100:600, :2]), rms(batch[100:600] - true[100:600, :2])
    print(f"live {1e3 * live:.3f} mm, batch {1e3 * full:.3f} mm, raw 1.000")
    assert live <= 1.05 * full and live < 0.8e-3
    # around the occlusion the marker comes out as measured (NaN inside), never invented
    near = slice(300 - 12, 310 + 12)
    assert np.isnan(out[300:310, 2]).all()
    assert np.array_equal(out[near, 2][~np.isnan(out[near, 2])], noisy[near, 2][~np.isnan(noisy[near, 2])])
    lp.reset()
    assert lp.push(noisy[0], "a") is None
    with pytest.raises(ValueError, match="lag of 8 frames or more"):
        FixedLagLowpass(4, RATE, 10.0, 5)
