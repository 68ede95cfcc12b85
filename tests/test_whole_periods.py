"""Whole periods the stamps cannot tell apart (`radar_odom.io.timebase`), decided by the match
(`radar_odom.odometry.whole_periods`).

The same stamps ``…, t, t + 2P, t + 3P, …`` are one sweep dropped before the third stamp, or the third
stamp a period late with the next sweep dropped. Simulated drives (fresh seeds ≥ 10000) are stamped
both ways (`radar_odom.sim.host_stamps`); the odometer with the recording's time base must read each
as the truth has it. The shipped cart-0.4 model.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from radar_odom.errors import SequenceError
from radar_odom.io.timebase import (
    assign_sweep_indices,
    fit_time_base,
    local_phase_us,
    slot_path_costs,
    tolerance_us,
)
from radar_odom.odometry.whole_periods import choose_hypothesis, rotation_period_s
from radar_odom.sim.host_stamps import host_stamps, timed

P_US = 250_000
T0_US = 1_549_986_548_000_000


def _true_us(n):
    return T0_US + P_US * np.arange(n)


# --------------------------------------------------------------------------- the time base
def test_a_dropped_sweep_lists_the_reading_with_its_stamp_a_period_late():
    keep = [k for k in range(60) if k != 30]
    tb = fit_time_base(host_stamps(_true_us(60), keep, jitter_us=4_000, seed=10_050))
    assert tb.alternatives == ((30, (31, 30)),)  # the fit's k first: the drop before sweep 31
    assert tb.candidates(30) == (31, 30) and tb.candidates(29) == (29,)
    assert tb.time_at(30, 30) - tb.times_us[30] == pytest.approx(-P_US, abs=100)
    assert "1 sweep time the stamps cannot place" in tb.summary()
    late = tb.decided({30: 30})  # sweep 30 stamped a period late, sweep 31 dropped
    assert late.sweep_index[29:32].tolist() == [29, 30, 32] and late.dropped == 1
    assert late.late.tolist() == [30] and late.alternatives == () and late.decided_by_match == (30,)
    assert "1 sweep stamps were late" in late.summary() and "1 decided by the match" in late.summary()
    assert "cannot place" not in late.summary()
    with pytest.raises(SequenceError, match="none of the stamps' readings"):
        tb.decided({30: 28})


def test_stamps_that_decide_for_themselves_list_no_alternative():
    n = 200
    jitter = host_stamps(_true_us(n), range(n), jitter_us=6_000, seed=10_051)
    early = jitter.copy()
    early[100] -= 170_000
    late_run = jitter.astype(np.float64)
    late_run[80:] += np.maximum(263_000 - 20_000 * np.arange(n - 80), 0)  # the shared drive's late run
    for stamps in (jitter, early, late_run.astype(np.int64)):
        tb = fit_time_base(stamps)
        assert tb.alternatives == () and tb.dropped == 0


def test_slot_path_costs_are_least_on_the_fitted_path():
    rng = np.random.default_rng(10_052)
    k = np.cumsum(rng.choice([1, 1, 1, 1, 2, 3], size=150))
    stamps = host_stamps(T0_US + P_US * k, range(150), jitter_us=4_000, seed=10_052)
    tol = tolerance_us(np.diff(stamps).astype(np.float64), P_US)
    base = stamps[0] + local_phase_us(stamps, P_US, tol)
    fitted = assign_sweep_indices(stamps, base, P_US, tol)
    slots, cost = slot_path_costs(stamps, base, P_US, tol)
    best = cost.min()
    np.testing.assert_allclose(cost.min(axis=1), best)  # every stamp lies on the cheapest path
    on_path = cost[np.arange(150), np.argmax(slots == fitted[:, None], axis=1)]
    np.testing.assert_allclose(on_path, best)
    assert np.array_equal(fitted - fitted[0], k - k[0])


def test_the_likelier_prediction_wins_and_none_without_a_lead():
    cov = np.diag([0.1**2, 0.1**2, math.radians(0.3) ** 2])
    one, two = (np.array([2.5, 0.0, 0.0]), cov), (np.array([5.0, 0.0, 0.0]), cov)
    assert choose_hypothesis(np.array([5.05, 0.02, 0.0]), cov, [two, one])[0] == 0
    assert choose_hypothesis(np.array([2.45, 0.0, 0.0]), cov, [two, one])[0] == 1
    still = (np.zeros(3), cov)
    chosen, lead = choose_hypothesis(np.array([0.01, 0.0, 0.0]), cov, [still, still])
    assert chosen is None and lead == pytest.approx(0.0)


# --------------------------------------------------------------------------- simulated drives
def _drive(seed, frames, speed_mps):
    from radar_odom.se2 import chain_relative
    from radar_odom.sim.scenarios import get_scenario
    from radar_odom.sim.simulator import simulate_drive

    base = get_scenario("urban")
    fr = list(simulate_drive(seed, frames, replace(base, drive=replace(base.drive, constant_speed_mps=speed_mps))))
    return [f.scan for f in fr], chain_relative(np.array([f.pose_rel for f in fr[1:]]))


@pytest.fixture(scope="module")
def city():
    return _drive(10_053, 14, 10.0)


def _run(scans, poses, keep, stamps, **odo_args):
    """(the odometer's time base, per-step errors (m, °) against the truth between the kept sweeps)."""
    import radar_odom
    from radar_odom.odometry.odometer import RadarOdometer
    from radar_odom.se2 import invert, to_xyyaw, wrap_angle

    tb = fit_time_base(stamps)
    odo = RadarOdometer(radar_odom.pretrained("cart-0.4"), threads=1,
                        **({"time_base": tb} if not odo_args else odo_args))
    steps = list(odo.iter_estimates(timed([scans[k] for k in keep], tb.times_us), prefetch=0))
    ests = [e for _, _, e in steps][1:]
    # the stream hands out the decided times, the trajectory's and the decided time base's
    assert [t for _, t, _ in steps] == odo.trajectory.timestamps_us.tolist()
    if odo.time_base is not None:
        assert odo.time_base.times_us.tolist() == odo.trajectory.timestamps_us.tolist()
    errors = []
    for j, est in enumerate(ests):
        truth = to_xyyaw(invert(poses[keep[j]]) @ poses[keep[j + 1]])
        errors.append((math.hypot(*(est.pose[:2] - truth[:2])), abs(math.degrees(wrap_angle(est.pose[2] - truth[2])))))
    return odo.time_base, tb, np.array(errors)


@pytest.mark.slow
@pytest.mark.parametrize("truth", ["drop", "late"])
def test_a_drop_and_a_late_stamp_with_the_same_stamps_are_each_read_as_the_truth(city, truth):
    scans, poses = city
    at = 8
    keep = [k for k in range(len(scans)) if k != (at if truth == "drop" else at + 1)]
    true_us = [s.timestamp_us for s in scans]
    stamps = host_stamps(true_us, keep, {at: P_US} if truth == "late" else None, jitter_us=4_000, seed=10_054)
    decided, fitted, errors = _run(scans, poses, keep, stamps)
    assert fitted.alternatives == ((at, (at + 1, at)),)  # the same stamps either way: the fit reads a drop
    assert np.array_equal(decided.sweep_index, np.asarray(keep) - keep[0])  # the match: the truth's k
    assert decided.decided_by_match == (at,) and decided.alternatives == ()
    assert errors[:, 0].max() < 0.3 and errors[:, 1].max() < 0.5, errors  # the poses follow the truth
    if truth == "late":  # the fit's reading alone: a step beside that sweep metres off (a period is 2.5 m)
        _, _, before = _run(scans, poses, keep, stamps, sweep_period_s=fitted.period_s)
        assert before[at - 1:at + 1, 0].max() > 2.0


@pytest.mark.slow
def test_every_other_sweep_dropped_without_a_hint_takes_the_sweeps_own_turn(city):
    scans, poses = city
    keep = list(range(0, 12, 2))  # every sweep a gap to cross and a reading to decide: a short stream
    stamps = host_stamps([s.timestamp_us for s in scans], keep, jitter_us=1_000, seed=10_055)
    decided, fitted, errors = _run(scans, poses, keep, stamps)
    # the stamps alone: 0.5 s or 0.25 s; every sweep's time the same either way
    assert fitted.period_us == pytest.approx(2 * P_US, rel=2e-3) and fitted.period_from == "stamps"
    assert rotation_period_s(scans[0]) == pytest.approx(P_US * 1e-6, rel=0.01)
    assert decided.period_us == pytest.approx(P_US, rel=2e-3) and "own turn" in decided.period_from
    assert np.array_equal(decided.sweep_index, np.asarray(keep))
    assert errors[:, 0].max() < 0.3 and errors[:, 1].max() < 0.5, errors


def test_a_sweep_without_azimuth_times_gives_no_turn(city):
    scan = city[0][0]
    assert rotation_period_s(replace(scan, timestamps_us=np.full_like(scan.timestamps_us, scan.timestamp_us))) is None


def test_the_odometer_refuses_a_time_base_that_is_not_one(tiny_model):
    from radar_odom.errors import ConfigError
    from radar_odom.odometry.odometer import RadarOdometer

    with pytest.raises(ConfigError, match="time_base must be a radar_odom.io.timebase.TimeBase"):
        RadarOdometer(tiny_model, time_base=[0, 250_000])
    tb = fit_time_base(_true_us(10))
    odo = RadarOdometer(tiny_model, time_base=tb)
    assert np.array_equal(odo.time_base.times_us, tb.times_us) and odo._period.known_s == pytest.approx(0.25)


def test_radar_odom_run_prints_the_decided_count_once(tmp_path, capsys, monkeypatch):
    import radar_odom.commands.run_sequence as run_mod
    from radar_odom.commands.cli import main

    keep = [k for k in range(40) if k != 20]
    decided = fit_time_base(host_stamps(_true_us(40), keep, seed=10_056)).decided({20: 20})
    rec = tmp_path / "drive.mcap"
    rec.write_bytes(b"")

    class Result:  # what run_sequence hands back, less the odometry
        reference, reference_note, estimates, timestamps_us, metrics, step_errors = None, "", [], [], None, None
        num_degenerate, seconds_per_step, files, problems, throughput, skipped = 0, 0.0, {}, [], None, []
        time_base = decided

    monkeypatch.setattr(run_mod, "run_sequence", lambda *a, **k: Result())
    main(["run", str(rec), "-o", str(tmp_path / "out"), "--no-plot"])
    out = capsys.readouterr().out
    assert out.count("1 decided by the match") == 1 and "sweep times: 1 sweep stamps were late" in out
