"""Late sweep stamps put back on the sensor's period (`radar_odom.io.stamps`)."""
from __future__ import annotations

import numpy as np
import pytest

from radar_odom.errors import SequenceError, StampWarning
from radar_odom.io.stamps import LOOKAHEAD_SWEEPS, repair_late_stamps

PERIOD_US = 249_900.0


def _on_period(n: int, jitter_us: float = 0.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(true sweep times, stamps late by a host's jitter in [0, jitter_us]) of n sweeps, µs."""
    true = 1_549_986_548_000_000 + np.arange(n) * PERIOD_US
    late = np.random.default_rng(seed).uniform(0.0, jitter_us, n)
    return true, np.round(true + late).astype(np.int64)


def _late_run(stamps: np.ndarray, at: int, late_us: float, catch_up_us: float) -> np.ndarray:
    """Stamps from ``at`` on late by ``late_us``, less ``catch_up_us`` per sweep until back on time
    (what the shared RADIATE drive shows three times: ≈ 0.25 s late, then ≈ 0.23 s intervals)."""
    out = stamps.astype(np.float64).copy()
    k = np.arange(out.size - at)
    out[at:] += np.maximum(late_us - catch_up_us * k, 0.0)
    return np.round(out).astype(np.int64)


def test_a_late_run_is_put_back_on_the_period():
    true, stamps = _on_period(120)
    late = _late_run(stamps, 50, 260_000.0, 19_000.0)
    rep = repair_late_stamps(late)
    # the sensor's period, not the late stamps' mean interval
    assert rep.period_us == pytest.approx(PERIOD_US, rel=2e-3)
    # every stamp within a few ms of the truth (what is left: lookahead × the period's shortfall)
    assert np.max(np.abs(rep.timestamps_us - true)) < 8_000
    # the interval that looked like a dropped sweep is one period again
    assert np.diff(rep.timestamps_us)[49] == pytest.approx(PERIOD_US, abs=8_000)
    assert np.diff(late)[49] > 1.9 * PERIOD_US
    # only the late run moved, by what it was late
    assert set(rep.late) == set(np.flatnonzero(late - true > 0.02 * rep.period_us))
    assert "late (up to 260 ms, in 1 run" in rep.summary()


def test_a_dropped_sweep_keeps_its_gap():
    true, stamps = _on_period(120)
    dropped = np.delete(stamps, 60)  # sweep 60 never arrived: the later stamps stay a period on
    rep = repair_late_stamps(dropped)
    assert np.array_equal(rep.timestamps_us, dropped)
    assert rep.late.size == 0 and rep.summary() == ""


def test_host_jitter_is_left_alone():
    _, stamps = _on_period(200, jitter_us=10_000.0)
    rep = repair_late_stamps(stamps)
    assert np.array_equal(rep.timestamps_us, stamps)


def test_a_late_run_next_to_a_dropped_sweep_is_repaired_and_the_gap_kept():
    true, stamps = _on_period(150)
    late = _late_run(stamps, 40, 240_000.0, 18_000.0)
    both = np.delete(late, 100)
    true = np.delete(true, 100)
    rep = repair_late_stamps(both)
    assert np.max(np.abs(rep.timestamps_us - true)) < 8_000
    assert np.diff(rep.timestamps_us)[99] == pytest.approx(2 * PERIOD_US, abs=8_000)


def test_repaired_stamps_still_increase_and_are_never_later():
    rng = np.random.default_rng(3)
    for trial in range(20):
        true, stamps = _on_period(80, jitter_us=12_000.0, seed=trial)
        for at in rng.choice(70, 3, replace=False):
            stamps = _late_run(stamps, int(at), float(rng.uniform(50_000, 300_000)), float(rng.uniform(5_000, 30_000)))
        rep = repair_late_stamps(stamps)
        assert np.all(np.diff(rep.timestamps_us) > 0)
        assert np.all(rep.corrections_us >= 0)
        assert np.array_equal(rep.timestamps_us + rep.corrections_us, stamps)


def test_the_lookahead_bounds_what_can_be_repaired():
    # a run that takes longer to catch up than the lookahead is only repaired where a later stamp
    # within reach is on time again
    true, stamps = _on_period(200)
    late = _late_run(stamps, 50, 250_000.0, 250_000.0 / (3 * LOOKAHEAD_SWEEPS))
    rep = repair_late_stamps(late)
    # sweep 50 is bounded by sweep 50 + lookahead, still 2/3 as late: repaired by a third only
    assert rep.timestamps_us[50] - true[50] == pytest.approx(250_000 * 2 / 3, abs=8_000)
    # sweep 50 + 2·lookahead reaches the first stamp on time again: repaired in full
    at = 50 + 2 * LOOKAHEAD_SWEEPS
    assert late[at] - true[at] > 50_000 and abs(rep.timestamps_us[at] - true[at]) < 8_000


def test_few_stamps_are_returned_unchanged_and_bad_ones_refused():
    rep = repair_late_stamps([0, 250_000, 750_000])
    assert np.array_equal(rep.timestamps_us, [0, 250_000, 750_000]) and rep.period_us == 0.0
    with pytest.raises(SequenceError, match="increase strictly"):
        repair_late_stamps([0, 250_000, 250_000, 500_000, 750_000])
    with pytest.raises(SequenceError, match="increase strictly"):
        repair_late_stamps([0, 250_000, 200_000])
    assert repair_late_stamps([5]).timestamps_us.tolist() == [5] and repair_late_stamps([]).late.size == 0


@pytest.mark.real
def test_real_radiate_drive_has_three_late_runs_and_no_dropped_sweep(real_data_dir):
    from radar_odom.io import read_sequence

    drive = real_data_dir / "radiate-2019-02-12-edinburgh"
    if not (drive / "Navtech_Polar.txt").is_file():
        pytest.skip(f"no RADIATE city drive at {drive}")
    seq = read_sequence(drive, repair_stamps=False)  # as recorded (read_sequence repairs them by default)
    rep = repair_late_stamps(seq.timestamps_us)
    raw = np.diff(seq.timestamps_us) / 1e6
    fixed = np.diff(rep.timestamps_us) / 1e6
    # three intervals of ≈ 0.5 s with consecutive frame numbers (sweeps 135, 203, 245)
    assert list(np.flatnonzero(raw > 0.4) + 1) == [135, 203, 245]
    # all one period once repaired, and each late run starts where the long interval was
    assert fixed.max() < 0.28 and fixed.min() > 0.22
    starts = [int(i) for i in rep.late if i - 1 not in set(rep.late)]
    assert starts == [135, 203, 245]
    assert 200_000 < rep.corrections_us.max() < 300_000
    # the median interval: 0.65 ms short of the stamps' long-run slope (the catch-ups' short intervals)
    assert rep.period_us == pytest.approx(249_250, abs=300)
    # what read_sequence gives by default: the same repair, said once
    with pytest.warns(StampWarning, match="44 sweep stamps were late"):
        repaired = read_sequence(drive)
    np.testing.assert_array_equal(repaired.timestamps_us, rep.timestamps_us)
