"""The constant-velocity motion prior: information-form fusion, yaw wrapping, gating, lock-in,
the dominance taper, external odometry, and the prior inside `RadarOdometer`.

Most tests feed synthetic (measurement, covariance) sequences to `MotionPrior` exactly as the
odometer does (no ONNX); the last ones run the shipped ``cart-0.8`` model on a short simulated
drive.
"""
import numpy as np
import pytest

from radar_odom.odometry.motion_prior import (
    CHI2_3DOF_999,
    GATED,
    PRIOR_DOMINATED,
    PRIOR_RESET,
    ExternalOdometry,
    MotionPrior,
    MotionPriorConfig,
    fuse,
    inv_psd,
    taper_prior,
)
from radar_odom.se2 import chain_relative, to_xyyaw

DT = 0.25  # 4 Hz
DEG = np.pi / 180
FLAGS = {"degenerate", "bridged", "prior_dominated", "gated", "prior_reset",
         "blank", "saturated", "invalid_rows", "nonfinite", "no_reference"}


def replay(measurements, covs, config=None, dt=DT, prior=None):
    """Feed a sequence to a `MotionPrior` as `RadarOdometer` does (consecutive sweeps).

    Returns (fused poses float[N, 3], list of `PriorStep`). A gated step leaves the velocity as
    it was, so the next prediction starts one interval later (``lead_s``), as in the odometer.
    """
    prior = prior or MotionPrior(config)
    lead, out = 0.0, []
    for m, c in zip(measurements, covs):
        res = prior.update(m, c, dt, lead_s=lead)
        lead = lead + dt if GATED in res.flags else 0.0
        out.append(res)
    return np.array([r.pose for r in out]), out


def noisy(truth, sigmas, rng):
    """Measurements = truth + N(0, σ²) per component, and their (honest) covariances."""
    truth = np.asarray(truth, dtype=np.float64)
    meas = truth + rng.normal(size=truth.shape) * sigmas
    return meas, np.tile(np.diag(np.square(sigmas)), (len(truth), 1, 1))


def speed_profile_rel(speeds_at_ends, yaw_rates=None, dt=DT):
    """Relative poses of intervals with linearly changing speed between the given end speeds."""
    v = np.asarray(speeds_at_ends, dtype=np.float64)
    x = 0.5 * (v[:-1] + v[1:]) * dt
    w = np.zeros(len(x)) if yaw_rates is None else np.asarray(yaw_rates, dtype=np.float64)
    th = w * dt
    # circular arc at the interval's mean speed and constant yaw rate
    s = np.where(np.abs(th) > 1e-9, np.sin(th) / np.where(th == 0, 1, th), 1.0)
    c = np.where(np.abs(th) > 1e-9, (1 - np.cos(th)) / np.where(th == 0, 1, th), 0.0)
    return np.stack([x * s, x * c, th], axis=1)


# --------------------------------------------------------------------------- fusion
def test_fuse_is_the_information_form_on_a_hand_computed_diagonal_case():
    m, cm = [1.0, 2.0, 0.1], np.diag([1.0, 4.0, 0.01])
    p, cp = [3.0, 0.0, 0.3], np.diag([1.0, 1.0, 0.04])
    f, cf, info = fuse(m, cm, p, cp)
    # per axis: μ = (m/σm² + p/σp²) / (1/σm² + 1/σp²), σ² = 1 / (1/σm² + 1/σp²)
    np.testing.assert_allclose(f, [2.0, 0.4, 0.14], atol=1e-12)
    np.testing.assert_allclose(cf, np.diag([0.5, 0.8, 0.008]), atol=1e-12)
    # innovation m − p = (−2, 2, −0.2) under Σm + Σp = diag(2, 5, 0.05): 2 + 0.8 + 0.8
    np.testing.assert_allclose(info["innovation"], [-2.0, 2.0, -0.2], atol=1e-12)
    assert info["d2"] == pytest.approx(3.6)


def test_fuse_with_full_covariances_is_symmetric_psd_and_matches_the_formula():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    cm, cp = a @ a.T + 0.1 * np.eye(3), b @ b.T + 0.1 * np.eye(3)
    m, p = np.array([1.0, -0.5, 0.2]), np.array([0.7, 0.1, -0.1])
    f, cf, _ = fuse(m, cm, p, cp)
    im, ip = np.linalg.inv(cm), np.linalg.inv(cp)
    want_cov = np.linalg.inv(im + ip)
    np.testing.assert_allclose(cf, want_cov, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(f, want_cov @ (im @ m + ip @ p), rtol=1e-9, atol=1e-12)
    assert np.array_equal(cf, cf.T) and np.linalg.eigvalsh(cf).min() > 0
    # fusing only ever adds information
    assert np.all(np.linalg.eigvalsh(cm - cf) > -1e-12) and np.all(np.linalg.eigvalsh(cp - cf) > -1e-12)


def test_yaw_wraps_in_fusion_and_in_the_innovation():
    cm = cp = np.diag([0.1, 0.1, (2 * DEG) ** 2])
    # 179° and −179° are 2° apart: they fuse to ±180°, not to 0°
    f, _, info = fuse([1.0, 0.0, np.pi - DEG], cm, [1.0, 0.0, -np.pi + DEG], cp)
    assert abs(abs(f[2]) - np.pi) < 1e-9 and -np.pi < f[2] <= np.pi
    assert info["innovation"][2] == pytest.approx(-2 * DEG)
    assert info["d2"] == pytest.approx((2 * DEG) ** 2 / (2 * (2 * DEG) ** 2))
    # unequal weights stay on the short arc: 3/4 of the way from −179° towards 179° (via 180°)
    f, _, _ = fuse([0.0, 0.0, np.pi - DEG], np.diag([1, 1, (DEG) ** 2]),
                   [0.0, 0.0, -np.pi + DEG], np.diag([1, 1, (np.sqrt(3) * DEG) ** 2]))
    assert f[2] == pytest.approx(np.pi - 0.5 * DEG)


def test_singular_or_degenerate_covariances_never_give_nan():
    zero = np.zeros((3, 3))
    rank1 = np.outer([1.0, 2.0, 0.0], [1.0, 2.0, 0.0])
    huge = np.diag([1e12, 1e-12, 1.0])
    for cm in (zero, rank1, huge, np.diag([1e-30, 1.0, 1.0])):
        for cp in (zero, rank1, np.eye(3)):
            f, cf, info = fuse([1.0, 2.0, 0.3], cm, [0.0, 0.0, 0.0], cp)
            assert np.all(np.isfinite(f)) and np.all(np.isfinite(cf)) and np.isfinite(info["d2"])
            assert np.allclose(cf, cf.T) and np.linalg.eigvalsh(cf).min() >= -1e-9 * max(1.0, np.abs(cf).max())
    assert np.all(np.isfinite(inv_psd(zero)))
    prior = MotionPrior()
    prior.observe([2.5, 0.0, 0.0], zero, DT)
    res = prior.update([2.5, 0.0, 0.0], zero, DT)
    assert np.all(np.isfinite(res.pose)) and np.all(np.isfinite(res.covariance))
    with pytest.raises(ValueError, match="not finite"):
        fuse([np.nan, 0, 0], np.eye(3), [0, 0, 0], np.eye(3))


def test_first_step_has_nothing_to_fuse():
    prior = MotionPrior()
    assert not prior.ready and prior.predict(DT) is None
    res = prior.update([2.5, 0.1, 0.01], np.diag([0.01, 0.01, 1e-4]), DT)
    np.testing.assert_array_equal(res.pose, [2.5, 0.1, 0.01])
    assert res.flags == frozenset() and res.d2 is None and res.prior is None
    np.testing.assert_allclose(prior.velocity, [10.0, 0.4, 0.04])
    pose, cov = prior.predict(2 * DT)  # constant velocity over a longer interval
    np.testing.assert_allclose(pose, [5.0, 0.2, 0.02])
    # the velocity's own spread scales with dt², and accelerations add on top
    assert np.all(np.diag(cov) > 4 * np.array([0.01, 0.01, 1e-4]))
    prior.reset()
    assert not prior.ready


def test_prediction_covariance_is_physical_and_grows_with_the_lead():
    cfg = MotionPriorConfig()
    prior = MotionPrior(cfg)
    prior.observe([2.5, 0.0, 0.0], np.zeros((3, 3)), DT)
    _, cov = prior.predict(DT)
    # τ = dt between consecutive intervals: a·dt² per axis (0.25 m, 2.5° at 4 Hz)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [4 * DT**2, 4 * DT**2, 40 * DEG * DT**2])
    _, later = prior.predict(DT, lead_s=DT)  # after a skipped sweep: τ = 2 dt
    np.testing.assert_allclose(later, 4 * cov)


# --------------------------------------------------------------------------- constrained / unconstrained
def test_unconstrained_direction_is_carried_by_the_prior_a_tight_one_is_not_pulled():
    prior = MotionPrior()
    prior.observe([2.0, 0.0, 0.0], np.diag([0.01, 0.01, (0.5 * DEG) ** 2]), DT)
    pred, pred_cov = prior.predict(DT)
    # a corridor: x unconstrained (σ 30 m), y and yaw pinned down (σ 3 cm, 0.2°), all off the prediction
    m = np.array([6.0, 0.3, 2 * DEG])
    cm = np.diag([30.0**2, 0.03**2, (0.2 * DEG) ** 2])
    res = prior.update(m, cm, DT)
    assert abs(res.pose[0] - pred[0]) < 0.01  # x from the prior
    assert res.filter_covariance[0, 0] == pytest.approx(pred_cov[0, 0], rel=1e-3)
    # reported: the prior's information discounted k-fold where it carries the estimate...
    k = MotionPriorConfig().report_prior_scale
    assert res.covariance[0, 0] == pytest.approx(k * pred_cov[0, 0], rel=0.01)
    # ...and hardly at all where the measurement does
    assert res.covariance[1, 1] == pytest.approx(res.filter_covariance[1, 1], rel=0.01)
    assert res.covariance[2, 2] == pytest.approx(res.filter_covariance[2, 2], rel=0.01)
    assert abs(res.pose[1] - m[1]) < 0.003 * abs(m[1] - pred[1])  # y: not pulled
    assert abs(res.pose[2] - m[2]) < 0.003 * abs(m[2] - pred[2])  # yaw: not pulled
    assert res.flags == {PRIOR_DOMINATED} and res.prior_share > 0.9
    # plain fusion would pull y by σm²/(σm² + σp²) ≈ 1.3 % of the innovation: the taper cuts it to ~0
    plain, _, _ = fuse(m, cm, pred, pred_cov)
    assert abs(plain[1] - m[1]) > 5 * abs(res.pose[1] - m[1])


def test_taper_leaves_a_weaker_measurement_alone_and_divides_a_dominated_prior():
    cp = np.diag([0.1, 0.2, 0.3])
    np.testing.assert_allclose(taper_prior(np.diag([1.0, 1.0, 1.0]), cp), cp, rtol=1e-12)  # all weaker
    # y: measurement 20× as informative → prior variance × 20; x, yaw unchanged
    np.testing.assert_allclose(taper_prior(np.diag([1.0, 0.01, 1.0]), cp), np.diag([0.1, 4.0, 0.3]), rtol=1e-9)


def test_well_constrained_steady_drive_is_not_flagged_and_a_corridor_is():
    rng = np.random.default_rng(1)
    truth = np.tile([2.5, 0.0, 0.0], (12, 1))
    meas, covs = noisy(truth, [0.05, 0.05, 0.3 * DEG], rng)
    _, steps = replay(meas, covs)
    assert not any(s.flags for s in steps)
    meas, covs = noisy(truth, [3.0, 0.05, 0.3 * DEG], rng)  # x unconstrained
    fused, steps = replay(meas, covs)
    # from the first estimate on, the prior's knowledge of x builds up until it dominates
    assert steps[1].prior_share < 2 / 3 and all(s.flags == {PRIOR_DOMINATED} for s in steps[3:])
    # and the prior does its job there: the x error shrinks well below the measurement's
    assert np.sqrt(np.mean((fused[4:, 0] - 2.5) ** 2)) < 0.5 * np.sqrt(np.mean((meas[4:, 0] - 2.5) ** 2))


# --------------------------------------------------------------------------- gating
def test_a_confident_yaw_spike_while_driving_straight_is_gated():
    rng = np.random.default_rng(2)
    truth = np.tile([2.5, 0.0, 0.0], (14, 1))  # 10 m/s, straight
    meas, covs = noisy(truth, [0.05, 0.05, 0.5 * DEG], rng)
    covs[:, 2, 2] = DEG**2  # claimed σ 1° (honest enough)
    meas[6, 2] = 14.2 * DEG  # a wrong correlation peak, confidently claimed
    fused, steps = replay(meas, covs)
    assert steps[6].flags == {GATED, PRIOR_DOMINATED} and steps[6].d2 > CHI2_3DOF_999
    assert abs(fused[6, 2]) < 1 * DEG  # the prior's yaw, not the spike
    assert [k for k, s in enumerate(steps) if s.flags] == [6]  # nothing else gated or flagged
    # the trajectory stays straight; the raw one turns by the spike
    raw_heading = to_xyyaw(chain_relative(meas)[-1])[2]
    fused_heading = to_xyyaw(chain_relative(fused)[-1])[2]
    assert raw_heading > 13 * DEG and abs(fused_heading) < 2 * DEG


def test_a_confident_spike_is_gated_whatever_its_claimed_sigma_but_a_turn_start_is_not():
    truth = np.tile([2.5, 0.0, 0.0], (6, 1))
    for sigma_deg in (0.6, 1.0):
        covs = np.tile(np.diag([0.05**2, 0.05**2, (sigma_deg * DEG) ** 2]), (6, 1, 1))
        spike = truth.copy()
        spike[4, 2] = 14.2 * DEG
        _, steps = replay(spike, covs)
        assert GATED in steps[4].flags, sigma_deg
        turn = truth.copy()
        turn[4:, 2] = 6.25 * DEG  # 0 → 25 °/s at once, sustained
        fused, steps = replay(turn, covs)
        assert not any(s.flags for s in steps), sigma_deg
        # the start of the turn is barely pulled towards the straight prediction: 2 % of 6.25°
        # at σ 1° (plain fusion: 12 %, 0.8°), and not at all from the next step on
        np.testing.assert_allclose(fused[4:, 2], 6.25 * DEG, atol=0.15 * DEG)
        np.testing.assert_allclose(fused[5:, 2], 6.25 * DEG, atol=0.02 * DEG)


def test_consecutive_gates_cannot_lock_onto_a_wrong_prediction():
    # the prior was told 0 yaw rate, then the measurements (σ 0.3°, consistent with each other)
    # show a steady 90 °/s spin — far outside the model, but real: it must be followed
    cfg = MotionPriorConfig(max_consecutive_gated=2)
    truth = np.vstack([np.tile([2.5, 0.0, 0.0], (4, 1)), np.tile([0.5, 0.0, 22.5 * DEG], (8, 1))])
    covs = np.tile(np.diag([0.02**2, 0.02**2, (0.3 * DEG) ** 2]), (12, 1, 1))
    fused, steps = replay(truth, covs, cfg)
    gated = [k for k, s in enumerate(steps) if GATED in s.flags]
    assert 1 <= len(gated) <= 2 and gated[0] == 4
    took = next(k for k in range(4, 12) if GATED not in steps[k].flags)
    assert took <= 4 + cfg.max_consecutive_gated
    # from there on the estimates follow the measurements and are never gated again
    assert not any(GATED in s.flags for s in steps[took:])
    np.testing.assert_allclose(fused[took + 1:, 2], 22.5 * DEG, atol=0.1 * DEG)


def test_after_max_gated_a_failing_measurement_is_taken_and_restarts_the_velocity():
    cfg = MotionPriorConfig(max_consecutive_gated=2, accel_std_mps2=0.1, lateral_accel_std_mps2=0.1,
                            yaw_accel_std_rps2=0.1 * DEG)  # a prior too stiff to follow anything
    truth = np.vstack([np.tile([2.5, 0.0, 0.0], (3, 1)), np.tile([1.0, 0.0, 0.0], (5, 1))])
    covs = np.tile(np.diag([0.01**2, 0.01**2, (0.1 * DEG) ** 2]), (8, 1, 1))
    fused, steps = replay(truth, covs, cfg)
    assert [sorted(s.flags) for s in steps[3:6]] == [[GATED, PRIOR_DOMINATED]] * 2 + [[PRIOR_RESET]]
    np.testing.assert_array_equal(fused[5], truth[5])  # taken as it is
    assert not any(s.flags for s in steps[6:])
    np.testing.assert_allclose(fused[6:], truth[6:], atol=1e-9)


# --------------------------------------------------------------------------- real manoeuvres
def _manoeuvre_errors(truth, sigmas, event_steps, config=None, seeds=200):
    """RMS error (per component) of raw and fused estimates at ``event_steps`` over many noise
    draws, and the number of gated steps there."""
    raw_sq, fused_sq, gated = 0.0, 0.0, 0
    for seed in range(seeds):
        meas, covs = noisy(truth, sigmas, np.random.default_rng(1000 + seed))
        fused, steps = replay(meas, covs, config)
        raw_sq = raw_sq + (meas[event_steps] - truth[event_steps]) ** 2
        fused_sq = fused_sq + (fused[event_steps] - truth[event_steps]) ** 2
        gated += sum(GATED in steps[k].flags for k in event_steps)
    return np.sqrt(raw_sq.mean(0) / seeds), np.sqrt(fused_sq.mean(0) / seeds), gated


def sharp_turn():
    """8 m/s straight, then at once 25 °/s for 10 steps (a 62° turn), then at once straight."""
    w = np.r_[np.zeros(6), np.full(10, 25 * DEG), np.zeros(6)]
    return speed_profile_rel(np.full(len(w) + 1, 8.0), w), [6, 7, 16, 17]


def sudden_stop():
    """10 m/s, braking at 10 m/s² to a stop within 1 s, standing, then driving off at 3 m/s²."""
    v = np.r_[np.full(7, 10.0), 10 - 10 * DT * np.arange(1, 5), np.zeros(4), 3 * DT * np.arange(1, 7)]
    return speed_profile_rel(v), list(range(6, 14))


@pytest.mark.parametrize("case", [sharp_turn, sudden_stop])
def test_a_real_sharp_turn_or_sudden_stop_is_followed_not_worse_than_raw(case):
    truth, events = case()
    sigmas = np.array([0.1, 0.05, 1.0 * DEG])  # the claimed covariance, and the true noise
    raw, fused, gated = _manoeuvre_errors(truth, sigmas, events)
    assert gated <= 0.01 * 200 * len(events)  # followed, not rejected
    assert np.all(fused <= raw * 1.02), (raw, fused)
    # the test can fail: plain fusion with a stiffer prior drags the estimates towards the
    # constant-velocity prediction and is worse at the manoeuvre
    stiff = MotionPriorConfig(accel_std_mps2=1.5, yaw_accel_std_rps2=15 * DEG, taper=False,
                              gate_d2=1e9)
    raw_s, fused_s, _ = _manoeuvre_errors(truth, sigmas, events, stiff, seeds=50)
    assert np.any(fused_s > raw_s * 1.1), (raw_s, fused_s)


# --------------------------------------------------------------------------- external odometry
def test_external_odometry_is_an_arc_with_a_full_rank_covariance():
    odo = ExternalOdometry(speed_mps=10.0, yaw_rate_rps=0.2)
    pose, cov = odo.relative_pose(DT)
    np.testing.assert_allclose(pose, [10 * np.sin(0.05) / 0.2, 10 * (1 - np.cos(0.05)) / 0.2, 0.05], rtol=1e-12)
    assert pose[1] > 0  # positive yaw rate turns right: y (right) grows
    assert np.linalg.eigvalsh(cov).min() > 0 and np.allclose(cov, cov.T)
    assert cov[0, 0] == pytest.approx((0.10 * 10.0 * DT) ** 2, rel=1e-3)  # default: 10 % of the speed
    _, slow = ExternalOdometry(speed_mps=0.5).relative_pose(DT)
    assert slow[0, 0] == pytest.approx((0.1 * DT) ** 2, rel=1e-3)  # its 0.1 m/s floor
    assert cov[2, 2] == pytest.approx((0.5 * DEG * DT) ** 2)
    straight, _ = ExternalOdometry(speed_mps=4.0, yaw_rate_rps=0.0).relative_pose(DT)
    np.testing.assert_allclose(straight, [1.0, 0.0, 0.0], atol=1e-15)
    # near-zero yaw rates use the series and agree with the closed form
    a, _ = ExternalOdometry(speed_mps=10.0, yaw_rate_rps=1e-5).relative_pose(DT)
    b, _ = ExternalOdometry(speed_mps=10.0, yaw_rate_rps=1e-3).relative_pose(DT)
    assert abs(a[1] - 10 * DT * 1e-5 * DT / 2) < 1e-12 and b[1] == pytest.approx(10 * DT * 1e-3 * DT / 2, rel=1e-3)
    _, speed_only = ExternalOdometry(speed_mps=10.0).relative_pose(DT)
    assert speed_only[2, 2] > 1e3  # no yaw rate: no yaw information
    _, gyro_only = ExternalOdometry(yaw_rate_rps=0.1).relative_pose(DT)
    assert gyro_only[0, 0] > 1e3 and gyro_only[2, 2] < 1e-4
    assert ExternalOdometry.coerce({"speed_mps": 1.0}) == ExternalOdometry(speed_mps=1.0)
    with pytest.raises(ValueError, match="speed_mps, yaw_rate_rps"):
        ExternalOdometry()
    with pytest.raises(TypeError):
        ExternalOdometry.coerce([1.0, 0.1])


@pytest.mark.parametrize("field, value, match", [
    ("speed_mps", "11", r"ExternalOdometry\.speed_mps must be a number \(float\), got str '11'"),
    ("yaw_rate_rps", [0.1], r"ExternalOdometry\.yaw_rate_rps must be a number \(float\), got list"),
    ("speed_std_mps", "0.5", r"ExternalOdometry\.speed_std_mps must be a number"),
    ("lateral_std_mps", True, r"ExternalOdometry\.lateral_std_mps must be a number"),
    ("speed_mps", float("nan"), r"speed_mps must be finite"),
    ("yaw_rate_std_rps", -0.1, r"yaw_rate_std_rps must be a positive number"),
])
def test_external_odometry_names_a_field_that_is_not_a_number(field, value, match):
    """ExternalOdometry(speed_mps='11') raised numpy's 'ufunc isfinite not supported' TypeError."""
    from radar_odom.errors import ConfigError

    kwargs = {"speed_mps": 10.0, field: value}
    with pytest.raises(ConfigError, match=match):
        ExternalOdometry(**kwargs)
    assert ExternalOdometry(speed_mps=np.float32(11), yaw_rate_rps=0).speed_mps == 11


def test_external_odometry_carries_what_the_radar_leaves_unconstrained():
    rng = np.random.default_rng(3)
    truth = speed_profile_rel(np.r_[np.full(6, 10.0), 10 - 2 * DT * np.arange(1, 9)])  # braking gently
    meas, covs = noisy(truth, [4.0, 0.05, 0.3 * DEG], rng)  # corridor: x unknown to the radar
    prior = MotionPrior(MotionPriorConfig())
    fused = []
    for k, (m, c) in enumerate(zip(meas, covs)):
        speed = truth[k, 0] / DT + rng.normal() * 0.05
        res = prior.update(m, c, DT, odometry=ExternalOdometry(speed_mps=speed, speed_std_mps=0.05))
        fused.append(res.pose)
    err = np.abs(np.array(fused)[:, 0] - truth[:, 0])
    assert err.max() < 0.1  # the wheel speed's 1.25 cm per step, not the radar's metres
    # odometry alone (the constant-velocity prediction switched off) does the same
    prior = MotionPrior()
    res = prior.update(meas[0], covs[0], DT, odometry={"speed_mps": truth[0, 0] / DT, "speed_std_mps": 0.05},
                       use_prediction=False)
    assert abs(res.pose[0] - truth[0, 0]) < 0.05


def test_a_wheel_speed_14_percent_off_does_not_overrule_a_sharp_radar_match():
    """The new user's case: driving straight at 11.4 m/s, radar matches with σ ≈ 2.4 cm, and the
    README's ExternalOdometry(speed_mps=9.8) (14 % low). With a fixed 0.1 m/s the wheel speed
    called the match a 16σ outlier: gated, the pose the wheel's. With the default (10 % of the
    speed) the match passes the gate and carries the pose to within a centimetre."""
    v_true = 11.4
    step = np.array([v_true * DT, 0.0, 0.0])
    cov = np.diag([0.024**2, 0.024**2, (0.05 * DEG) ** 2])
    results = {}
    for label, std in (("fixed 0.1 m/s", 0.1), ("default", None)):
        prior = MotionPrior(MotionPriorConfig())
        for _ in range(6):  # a steady drive: the constant-velocity prediction knows 11.4 m/s
            prior.update(step, cov, DT)
        results[label] = prior.update(step, cov, DT, odometry=ExternalOdometry(speed_mps=9.8, speed_std_mps=std))
    assert GATED in results["fixed 0.1 m/s"].flags
    assert abs(results["fixed 0.1 m/s"].pose[0] - step[0]) > 0.1  # the wheel's (and prediction's) blend won
    good = results["default"]
    assert not good.flags & {GATED, PRIOR_DOMINATED}, good.flags
    assert abs(good.pose[0] - step[0]) < 0.01


# --------------------------------------------------------------------------- in RadarOdometer
@pytest.fixture(scope="module")
def sim_frames():
    from radar_odom.sim import simulate_drive

    return list(simulate_drive(seed=5007, frames=8))


@pytest.fixture(scope="module")
def cart08():
    import radar_odom

    if "cart-0.8" not in radar_odom.pretrained_names():
        pytest.skip("no shipped cart-0.8 model in this checkout")
    return radar_odom.pretrained("cart-0.8")


def test_odometer_fuses_by_default_and_exposes_the_raw_measurement(cart08, sim_frames):
    from radar_odom.odometry.odometer import RadarOdometer

    on = RadarOdometer(cart08, threads=1)
    off = RadarOdometer(cart08, threads=1, motion_prior=False)
    assert on.motion_prior == MotionPriorConfig() and off.motion_prior is None
    ests_on = [on.step(f.scan) for f in sim_frames]
    ests_off = [off.step(f.scan) for f in sim_frames]
    assert ests_on[0] is None and ests_off[0] is None
    for k, (a, b) in enumerate(zip(ests_on[1:], ests_off[1:])):
        for est in (a, b):
            assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.covariance))
            assert est.measurement.shape == (3,) and est.measurement_covariance.shape == (3, 3)
            assert np.allclose(est.covariance, est.covariance.T) and np.linalg.eigvalsh(est.covariance).min() > 0
            assert est.flags <= FLAGS and not est.degenerate and not est.gated
        # the raw measurement is exactly what the odometer without the prior reports
        np.testing.assert_allclose(a.measurement, b.pose, atol=1e-9)
        np.testing.assert_allclose(a.measurement_covariance, b.covariance, atol=1e-12)
        np.testing.assert_array_equal(b.measurement, b.pose)
        assert not b.flags
        if k == 0:  # first estimate of the stream: nothing to fuse
            np.testing.assert_array_equal(a.pose, a.measurement)
        else:  # fused: never less certain than the measurement alone
            assert np.all(np.linalg.eigvalsh(a.measurement_covariance - a.covariance) > -1e-9)
    # the trajectory chains the fused poses
    chained = chain_relative(np.array([e.pose for e in ests_on[1:]]))
    np.testing.assert_allclose(on.trajectory.poses, chained, atol=1e-9)
    gt = np.array([f.pose_rel for f in sim_frames[1:]])
    err_on = np.abs(np.array([e.pose for e in ests_on[1:]]) - gt)[:, :2].mean()
    err_off = np.abs(np.array([e.pose for e in ests_off[1:]]) - gt)[:, :2].mean()
    assert err_on <= err_off + 0.05, (err_on, err_off)
    # reset() forgets the prior: the next stream's first estimate is the raw match again
    on.reset()
    on.step(sim_frames[0].scan)
    again = on.step(sim_frames[1].scan)
    np.testing.assert_array_equal(again.pose, again.measurement)


def test_odometer_degenerate_sweep_uses_the_prior_and_external_odometry_is_fused(cart08, sim_frames):
    from radar_odom.odometry.odometer import RadarOdometer, window_covariance
    from radar_odom.scan import RadarScan

    s = sim_frames[3].scan
    blank = RadarScan.from_arrays(s.timestamps_us, s.azimuths_rad, np.zeros_like(s.power),
                                  range_resolution_m=s.range_resolution_m, source="blank")
    odo = RadarOdometer(cart08, threads=1)
    ests = [odo.step(f.scan) for f in sim_frames[:3]] + [odo.step(blank), odo.step(sim_frames[4].scan)]
    deg, bridged = ests[3], ests[4]
    assert deg.degenerate and "blank" in deg.flags
    np.testing.assert_allclose(deg.pose, ests[2].pose, atol=1e-12)  # the prior's constant velocity
    np.testing.assert_allclose(deg.covariance, window_covariance(odo.profile))
    assert "bridged" in bridged.flags and np.all(np.isfinite(bridged.pose))
    np.testing.assert_allclose(odo.trajectory.poses[4], odo.trajectory.poses[3] @ chain_relative([bridged.pose])[1],
                               atol=1e-9)
    assert np.all(np.isfinite(bridged.measurement))
    # external odometry with the true motion, given per sweep, pulls the estimates to the truth
    # along the forward axis (where the simulated street leaves the radar least sure)
    odo = RadarOdometer(cart08, threads=1)
    odo.step(sim_frames[0].scan)
    errs_raw, errs_fused = [], []
    for prev, f in zip(sim_frames, sim_frames[1:]):
        dt = (f.scan.timestamp_us - prev.scan.timestamp_us) * 1e-6
        est = odo.step(f.scan, odometry={"speed_mps": f.pose_rel[0] / dt, "yaw_rate_rps": f.pose_rel[2] / dt,
                                         "speed_std_mps": 0.02})
        errs_raw.append(abs(est.measurement[0] - f.pose_rel[0]))
        errs_fused.append(abs(est.pose[0] - f.pose_rel[0]))
    assert max(errs_fused) < 0.05 and max(errs_fused) < max(errs_raw)
    with pytest.raises(TypeError):
        odo.step(sim_frames[0].scan, odometry=3.0)


def test_motion_prior_argument_is_checked(cart08):
    from radar_odom.odometry.odometer import RadarOdometer

    cfg = MotionPriorConfig(gate_d2=25.0)
    assert RadarOdometer(cart08, threads=1, motion_prior=cfg).motion_prior is cfg
    with pytest.raises(TypeError, match="motion_prior"):
        RadarOdometer(cart08, threads=1, motion_prior="yes")
    with pytest.raises(ValueError, match="gate_d2"):
        MotionPriorConfig(gate_d2=0.0)


def test_run_command_switches_the_prior_off(cart08, tmp_path, capsys):
    import csv

    from radar_odom.commands.cli import main
    from radar_odom.sim import write_drive

    drive = write_drive(tmp_path / "drive", seed=5007, frames=4, progress=False)
    rows = {}
    for name, extra in (("on", []), ("off", ["--no-motion-prior"])):
        out = tmp_path / name
        assert main(["run", str(drive), "--model", cart08, "-o", str(out), "--no-plot", *extra]) == 0
        with open(out / "estimates.csv", newline="") as f:
            rows[name] = list(csv.DictReader(f))
    printed = capsys.readouterr().out
    assert "motion prior off" in printed and "prior-dominated" in printed
    assert len(rows["on"]) == len(rows["off"]) == 3
    keys = ("x_m", "y_m", "yaw_rad")
    meas = ("meas_x_m", "meas_y_m", "meas_yaw_rad")
    for on, off in zip(rows["on"], rows["off"]):
        # without the prior the pose is the measurement; with it the measurement is still the raw one
        assert [off[k] for k in keys] == [off[k] for k in meas]
        np.testing.assert_allclose([float(on[k]) for k in meas], [float(off[k]) for k in keys], atol=1e-6)
    assert any(abs(float(on["x_m"]) - float(on["meas_x_m"])) > 1e-6 for on in rows["on"][1:])


@pytest.mark.torch
def test_evaluation_applies_the_runtime_prior_to_a_drive():
    pytest.importorskip("torch")
    from radar_odom_export.evaluate import with_motion_prior

    n = 12
    poses = np.tile([2.0, 0.0, 0.0], (n, 1))
    covs = np.tile(np.diag([0.05**2, 0.05**2, np.radians(0.5) ** 2]), (n, 1, 1))
    poses[8, 2] = np.radians(14.0)  # a confident yaw spike while driving straight
    fused, fcov = with_motion_prior(poses, covs)
    assert fused.shape == poses.shape and fcov.shape == covs.shape
    assert abs(fused[8, 2]) < np.radians(1.0)  # gated: the prediction stands in for it
    np.testing.assert_allclose(fused[[1, 5, 11], 0], 2.0, atol=0.01)


def test_reported_covariance_discounts_the_prior_but_the_filter_does_not():
    """k = 1 reports the filter's own covariance; k > 1 widens only the report: the estimates,
    flags and the velocity carried forward are the same for any k, and a gated step reports
    k × the prediction's covariance."""
    rng = np.random.default_rng(5)
    steps = [(np.array([2.0 + 0.05 * rng.standard_normal(), 0.01 * rng.standard_normal(), 0.0]),
              np.diag([rng.uniform(0.01, 4.0), 0.01, (0.3 * DEG) ** 2])) for _ in range(30)]
    steps[20] = (np.array([2.0, 0.0, 20 * DEG]), np.diag([0.01, 0.01, (0.3 * DEG) ** 2]))  # gated
    own, wide = MotionPrior(MotionPriorConfig(report_prior_scale=1.0)), MotionPrior(MotionPriorConfig())
    k = wide.config.report_prior_scale
    gated = []
    for i, (m, c) in enumerate(steps):
        a, b = own.update(m, c, DT), wide.update(m, c, DT)
        gated += [i] if GATED in b.flags else []
        np.testing.assert_array_equal(a.pose, b.pose)
        assert a.flags == b.flags and a.filter_covariance is None
        if i == 0:  # no prior yet: the measurement as it is
            np.testing.assert_array_equal(b.covariance, c)
            continue
        np.testing.assert_allclose(b.filter_covariance, a.covariance, rtol=1e-12)
        if GATED in b.flags:
            np.testing.assert_allclose(b.covariance, k * b.prior[1], rtol=1e-12)
            continue
        # between the filter's own and the measurement's: Σf ≤ Σr ≤ Σm (Loewner order)
        assert np.linalg.eigvalsh(b.covariance - a.covariance).min() > -1e-12
        assert np.linalg.eigvalsh(c - b.covariance).min() > -1e-12
    assert gated == [20]
    np.testing.assert_array_equal(own.velocity, wide.velocity)
    with pytest.raises(ValueError, match="report_prior_scale"):
        MotionPriorConfig(report_prior_scale=0.5)
