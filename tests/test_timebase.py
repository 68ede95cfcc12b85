"""One time base per recording: sweep times fitted on the sensor's period (`radar_odom.io.timebase`).

Synthetic stamps with known truth: sweep k at ``T0 + k·P``, stamped late by a delay ≥ 0 plus a
host's jitter; the hostile cases of issue 41 (a recording that drops every other sweep, one
early stamp) and the shared RADIATE drive's late runs with their catch-up.
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from radar_odom.errors import SequenceError
from radar_odom.io.timebase import fit_time_base, fundamental_period_us

PERIOD_US = 249_900.0
T0_US = 1_549_986_548_000_000.0


def _stamps(k, jitter_us: float = 0.0, seed: int = 10_000, period_us: float = PERIOD_US):
    """(stamps µs, true times µs) of the sweeps ``k`` (whole periods), stamped with uniform ±jitter."""
    true = T0_US + np.asarray(k, dtype=np.float64) * period_us
    jitter = np.random.default_rng(seed).uniform(-jitter_us, jitter_us, true.size)
    return np.round(true + jitter).astype(np.int64), true


def _late_run(stamps: np.ndarray, at: int, late_us: float, catch_up_us: float) -> np.ndarray:
    """Stamps from ``at`` on late by ``late_us``, less ``catch_up_us`` per sweep until back on time
    (the shared RADIATE drive, three times: ≈ 0.26 s late, then ≈ 0.23 s intervals for 12–14 sweeps)."""
    out = stamps.astype(np.float64).copy()
    out[at:] += np.maximum(late_us - catch_up_us * np.arange(out.size - at), 0.0)
    return np.round(out).astype(np.int64)


def test_jitter_only_is_host_jitter_not_a_moved_stamp():
    stamps, true = _stamps(np.arange(300), jitter_us=6_000.0)
    tb = fit_time_base(stamps)
    assert tb.period_us == pytest.approx(PERIOD_US, abs=50)
    assert tb.moved.size == 0 and tb.dropped == 0 and tb.summary() == ""
    assert np.array_equal(tb.sweep_index, np.arange(300))
    # the fitted times are the sensor's: closer to the truth than the stamps were
    assert np.max(np.abs(tb.times_us - true)) < 2_500 < np.max(np.abs(stamps - true))
    assert 6_000 < tb.tolerance_us < 15_000  # 3 σ of a uniform ±6 ms (σ 3.5 ms)


def test_late_runs_with_catch_up_are_put_back_and_nothing_dropped():
    stamps, true = _stamps(np.arange(280), jitter_us=5_000.0, seed=10_001)
    for at, late, catch in ((135, 263_000.0, 20_000.0), (203, 241_000.0, 18_000.0), (245, 218_000.0, 16_500.0)):
        stamps = _late_run(stamps, at, late, catch)
    assert np.diff(stamps).max() > 1.8 * PERIOD_US  # what looks like a dropped sweep, three times
    tb = fit_time_base(stamps)
    assert tb.dropped == 0 and np.array_equal(tb.sweep_index, np.arange(280))
    assert tb.period_us == pytest.approx(PERIOD_US, rel=1e-3)
    assert np.max(np.abs(tb.times_us - true)) < 3_000
    late = tb.late
    assert [int(i) for i in late if i - 1 not in set(late)] == [135, 203, 245]  # three runs, where they start
    assert tb.early.size == 0 and tb.corrections_us.max() == pytest.approx(263_000, abs=6_000)
    assert "late (up to 26" in tb.summary() and "in 3 runs" in tb.summary()


def test_one_early_stamp_does_not_move_the_stamps_before_it():
    stamps, true = _stamps(np.arange(200), jitter_us=5_000.0, seed=10_002)
    stamps[100] -= 170_000  # one stamp ahead of its neighbours' rhythm
    tb = fit_time_base(stamps)
    assert tb.moved.tolist() == [100] and tb.early.tolist() == [100]
    assert tb.corrections_us[100] == pytest.approx(-170_000, abs=8_000)
    assert np.max(np.abs(tb.corrections_us[82:100])) < tb.tolerance_us  # the 18 before it: jitter only
    assert np.array_equal(tb.sweep_index, np.arange(200)) and np.max(np.abs(tb.times_us - true)) < 3_000
    assert "1 early (up to 17" in tb.summary()


def test_every_other_sweep_dropped_in_part_keeps_the_sensor_period():
    # 60 sweeps, then only every other one for 200 periods (a few 1-period intervals left), then all again
    k = np.concatenate([np.arange(60), np.arange(60, 160, 2), [161, 162], np.arange(164, 260, 2), np.arange(260, 300)])
    stamps, true = _stamps(k, jitter_us=5_000.0, seed=10_003)
    tb = fit_time_base(stamps)
    assert tb.period_us == pytest.approx(PERIOD_US, rel=1e-3)
    assert np.array_equal(tb.sweep_index, k) and tb.dropped == int(np.sum(np.diff(k) - 1))
    assert tb.moved.size == 0 and np.max(np.abs(tb.times_us - true)) < 3_000  # nothing moved by seconds


def test_mostly_every_other_sweep_with_a_few_single_periods_is_the_sensor_period():
    # the common interval is two periods (a median "period" of 0.5 s); three stretches of single periods show P
    k = np.concatenate([np.arange(0, 200, 2), [201, 202], np.arange(204, 400, 2), [401, 402, 403],
                        np.arange(406, 600, 2)])
    stamps, true = _stamps(k, jitter_us=5_000.0, seed=10_004)
    assert np.median(np.diff(stamps)) > 1.9 * PERIOD_US
    tb = fit_time_base(stamps)
    assert tb.period_us == pytest.approx(PERIOD_US, rel=1e-3)
    assert np.array_equal(tb.sweep_index, k) and np.max(np.abs(tb.times_us - true)) < 3_000


def test_every_interval_two_periods_cannot_tell_the_period_and_says_so():
    stamps, true = _stamps(np.arange(0, 400, 2), jitter_us=5_000.0, seed=10_005)
    tb = fit_time_base(stamps)
    # the stamps alone: the largest consistent period, its whole fractions as candidates
    assert tb.period_us == pytest.approx(2 * PERIOD_US, rel=1e-3) and tb.period_from == "stamps"
    assert tb.candidate_periods_us[1] == pytest.approx(PERIOD_US, rel=1e-3)
    assert np.max(np.abs(tb.times_us - true)) < 3_000  # the same times either way
    # the sensor's nominal period picks among them: every other sweep dropped
    hinted = fit_time_base(stamps, period_hint_us=250_000)
    assert hinted.period_us == pytest.approx(PERIOD_US, rel=1e-3) and "nominal 250 ms" in hinted.period_from
    assert np.array_equal(hinted.sweep_index, np.arange(0, 400, 2)) and hinted.dropped == 199
    np.testing.assert_allclose(hinted.times_us, tb.times_us, atol=2)


@pytest.mark.parametrize("jump", [2, 3, 5, 8])
def test_dropped_sweeps_are_kept_as_gaps(jump):
    k = np.arange(240)
    k[120:] += jump - 1  # jump − 1 sweeps never arrived
    stamps, true = _stamps(k, jitter_us=5_000.0, seed=10_006 + jump)
    tb = fit_time_base(stamps)
    assert np.array_equal(tb.sweep_index, k) and tb.dropped == jump - 1 and tb.moved.size == 0
    assert np.max(np.abs(tb.times_us - true)) < 3_000
    assert f"{jump - 1} sweep{'s' if jump > 2 else ''} dropped" in tb.summary()


def test_a_late_run_next_to_a_dropped_sweep_is_repaired_and_the_gap_kept():
    stamps, true = _stamps(np.arange(150), jitter_us=5_000.0, seed=10_010)
    stamps = np.delete(_late_run(stamps, 40, 240_000.0, 18_000.0), 100)
    true = np.delete(true, 100)
    tb = fit_time_base(stamps)
    assert np.max(np.abs(tb.times_us - true)) < 3_000 and tb.dropped == 1
    assert np.diff(tb.sweep_index)[99] == 2


def test_slow_period_drift_is_followed():
    n = 2000  # the period grows 0.2 % over the recording (the host's clock against the sensor's)
    period = PERIOD_US * (1.0 + 0.002 * np.arange(n) / n)
    true = T0_US + np.concatenate([[0.0], np.cumsum(period[:-1])])
    stamps = np.round(true + np.random.default_rng(10_011).uniform(-5_000, 5_000, n)).astype(np.int64)
    tb = fit_time_base(stamps)
    assert np.max(np.abs(tb.times_us - true)) < 3_000 and tb.moved.size == 0
    assert tb.period_us == pytest.approx(period.mean(), rel=2e-4)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(period_ms=st.floats(80.0, 300.0), n=st.integers(60, 300), jitter_frac=st.floats(0.0, 0.03),
       drop_prob=st.floats(0.0, 0.05), runs=st.integers(0, 3), seed=st.integers(10_000, 2**31))
def test_fitted_times_are_within_jitter_of_the_truth_when_delays_are_bounded(period_ms, n, jitter_frac, drop_prob,
                                                                            runs, seed):
    """Whatever the period, drops, jitter (≤ 3 % of a period) and late runs (≤ 0.9 of a period late,
    caught up within 15 sweeps at ≤ 15 % of a period a sweep — the shared drive's ≈ 8 % —, ≥ 40 sweeps
    apart): k exact and
    every fitted time within the jitter of the truth. (A run a whole period late that starts right
    after a drop reads as well as the drop one sweep later: the fit takes the fewer late stamps;
    runs over a period late away from drops are `test_late_runs_with_catch_up_...`.)"""
    rng = np.random.default_rng(seed)
    p = period_ms * 1e3
    k = np.cumsum(np.where(rng.random(n) < drop_prob, rng.integers(2, 5, n), 1)) - 1
    jitter = jitter_frac * p
    true = T0_US + k * p
    stamps = true + rng.uniform(-jitter, jitter, n)
    for r in range(runs):
        at = 20 + 40 * r  # runs ≥ 40 sweeps apart (the shared drive's: 68 and 42)
        if at + 15 < n:
            late = rng.uniform(0.2, 0.9) * p
            length = int(rng.integers(int(np.ceil(late / (0.15 * p))), 16))  # caught up ≤ 15 % of a period a sweep
            stamps[at:at + length] += late * (1.0 - np.arange(length) / length)
    stamps = np.round(stamps).astype(np.int64)
    if np.any(np.diff(stamps) <= 0):
        return
    tb = fit_time_base(stamps)
    assert np.array_equal(np.diff(tb.sweep_index), np.diff(k))
    assert np.max(np.abs(tb.times_us - true)) <= jitter + 0.005 * p + 2


def test_fundamental_period_prefers_the_common_interval():
    d = np.full(100, 250_000.0)
    d[::10] = 500_000.0  # a few drops: still the common interval, not its half
    assert fundamental_period_us(d)[0] == pytest.approx(250_000.0)
    d = np.full(100, 500_000.0)
    d[[5, 40, 77]] = 250_000.0  # three single periods among double ones: the half
    assert fundamental_period_us(d)[0] == pytest.approx(250_000.0)


def test_few_stamps_are_kept_and_bad_ones_refused():
    tb = fit_time_base([0, 250_000, 750_000])
    assert np.array_equal(tb.times_us, [0, 250_000, 750_000]) and tb.period_us == 0.0 and tb.period_s is None
    assert tb.summary() == "" and tb.period_from == "too few stamps"
    with pytest.raises(SequenceError, match="increase strictly"):
        fit_time_base([0, 250_000, 250_000, 500_000, 750_000])
    with pytest.raises(SequenceError, match="increase strictly"):
        fit_time_base([0, 250_000, 200_000])
    assert fit_time_base([5]).times_us.tolist() == [5] and fit_time_base([]).moved.size == 0


def test_a_known_sweep_period_makes_two_periods_a_gap(tiny_model):
    from radar_odom import RadarOdometer
    from radar_odom.errors import ConfigError
    from radar_odom.odometry.stream_time import StreamClock

    median, known = StreamClock(), StreamClock(known_s=0.25)
    for _ in range(10):  # a stretch that dropped every other sweep, taken as one period a step: 0.5 s
        median.observe(0.5, 1)
    assert median.periods(0.5) == 1 and known.periods(0.5) == 2 and known.periods(0.3) == 1
    assert RadarOdometer(tiny_model, sweep_period_s=0.25).config.time.sweep_period_s == 0.25
    for bad in (0.0, -1.0, float("nan"), "fast"):
        with pytest.raises(ConfigError, match="sweep_period_s"):
            RadarOdometer(tiny_model, sweep_period_s=bad)


def test_the_reference_takes_the_readers_time_base_or_refuses_another():
    from radar_odom.errors import ConfigError
    from radar_odom.evaluation.reference import check_time_base

    stamps, _ = _stamps(np.arange(100), jitter_us=5_000.0, seed=10_012)
    stamps = _late_run(stamps, 40, 240_000.0, 20_000.0)
    tb = fit_time_base(stamps)
    check_time_base(tb, tb.times_us)  # the reader's times
    check_time_base(tb, stamps)  # or the stamps it was fitted on
    with pytest.raises(ConfigError, match="time_base does not belong"):
        check_time_base(tb, tb.times_us[:-1])
    with pytest.raises(ConfigError, match="time_base does not belong"):
        check_time_base(tb, tb.times_us + 1_000)


@pytest.mark.real
def test_real_radiate_drive_three_late_runs_no_dropped_sweep_and_one_answer(real_data_dir):
    """The shared city drive: three ≈ 0.5 s intervals with consecutive frame numbers are late runs
    (sweeps 135, 203, 245), not drops; the reader warns once and keeps the time base it used."""
    from radar_odom.errors import StampWarning
    from radar_odom.io import read_sequence

    drive = real_data_dir / "radiate-2019-02-12-edinburgh"
    if not (drive / "Navtech_Polar.txt").is_file():
        pytest.skip(f"no RADIATE city drive at {drive}")
    raw = read_sequence(drive, repair_stamps=False)
    assert raw.time_base is None and not raw.stamp_corrections_us.any()
    assert list(np.flatnonzero(np.diff(raw.timestamps_us) > 400_000) + 1) == [135, 203, 245]
    tb = fit_time_base(raw.timestamps_us, period_hint_us=250_000)
    assert tb.dropped == 0 and tb.early.size == 0 and tb.period_from == "stamps"
    assert tb.period_us == pytest.approx(249_820, abs=100)  # measured 249.82 ms (the median interval: 249.25)
    late = tb.late
    assert [int(i) for i in late if i - 1 not in set(late)] == [135, 203, 245]
    assert late.size == 39 and 260_000 < tb.corrections_us.max() < 270_000
    fixed = np.diff(tb.times_us) / 1e6
    assert fixed.min() > 0.249 and fixed.max() < 0.251  # every interval one period
    with pytest.warns(StampWarning, match=r"39 sweep stamps were late \(up to 264 ms, in 3 runs\)") as caught:
        seq = read_sequence(drive)
    assert len([w for w in caught if issubclass(w.category, StampWarning)]) == 1
    np.testing.assert_array_equal(seq.timestamps_us, tb.times_us)
    np.testing.assert_array_equal(seq.stamp_corrections_us, raw.timestamps_us - tb.times_us)
    assert seq.time_base is not None and np.array_equal(seq.time_base.times_us, tb.times_us)
