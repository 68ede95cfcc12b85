"""Motion compensation (de-skew), drawing a sweep in a moved frame, and crossing gaps.

Sweeps are rendered from a point-reflector world: for de-skew each azimuth row is seen from
where a moving sensor is at that row's time, so the expected Cartesian positions are known
exactly. The odometer tests use the committed tiny raw model (±2 cells of 1.6 m: ±3.2 m).
"""
import math

import cv2
import numpy as np
import pytest
from test_odometer import PERIOD_US, T0_US, drive, render_scan, world_points

from radar_odom import polar as P
from radar_odom.odometry.gaps import GAP, SweepPeriod, compose_residual
from radar_odom.odometry.odometer import RadarOdometer
from radar_odom.scan import RadarScan
from radar_odom.se2 import invert, se2, to_xyyaw

from fixtures import GEOM

A, B, RES_BIN = 720, 700, 0.1  # a fine radar: 0.5° azimuths, 70 m
GRID_RES, GRID_W = 0.2, 401


def skewed_scan(points_world, twist, t0_us=0, period_us=250_000, blur=True, taus_s=None):
    """Polar sweep of point reflectors seen by a sensor moving with body ``twist`` (at identity at
    the first azimuth): row a sees the points whose bearing from the sensor's pose at the row's
    time falls into the row. ``taus_s``: each row's time after the first (default: uniform over
    the period), also its timestamp."""
    taus = np.arange(A) * (period_us / A) * 1e-6 if taus_s is None else np.asarray(taus_s, dtype=np.float64)
    img = np.zeros((A, B), np.float32)
    sx, sy, syaw = P._sensor_pose_at(taus, twist)
    for a in range(A):
        inv = invert(se2(sx[a], sy[a], syaw[a]))
        q = points_world @ inv[:2, :2].T + inv[:2, 2]
        phi = np.mod(np.arctan2(q[:, 1], q[:, 0]), 2 * np.pi) / (2 * np.pi / A)
        near = np.abs(((phi - a + A / 2) % A) - A / 2) < 0.5  # bearing within this row's cell
        for r in np.hypot(q[near, 0], q[near, 1]):
            b = r / RES_BIN - 0.5
            b0 = int(math.floor(b))
            img[a, b0] += 1 - (b - b0)
            img[a, b0 + 1] += b - b0
    if blur:
        img = cv2.GaussianBlur(img, (0, 0), sigmaX=1.0, sigmaY=1.0)
    img = np.clip(img / img.max(), 0, 1).astype(np.float32)
    ts = t0_us + np.round(taus * 1e6).astype(np.int64)
    return RadarScan.from_arrays(ts, 2 * np.pi * np.arange(A) / A, img, range_resolution_m=RES_BIN)


def peak_xy(img, near_xy, win=6):
    """(x, y) in metres of the intensity-weighted centre around the pixel nearest ``near_xy``."""
    c = (GRID_W - 1) / 2
    r0, c0 = int(round(c - near_xy[0] / GRID_RES)), int(round(c + near_xy[1] / GRID_RES))
    patch = img[r0 - win:r0 + win + 1, c0 - win:c0 + win + 1].astype(np.float64)
    rr, cc = np.mgrid[r0 - win:r0 + win + 1, c0 - win:c0 + win + 1]
    w = patch.sum()
    return np.array([(c - (rr * patch).sum() / w) * GRID_RES, ((cc * patch).sum() / w - c) * GRID_RES])


# a point ahead-right, one behind-left (seen late in the sweep), one to the left
POINTS = np.array([[20.0, 12.0], [-18.0, -15.0], [3.0, -25.0]])


def test_static_maps_are_the_cached_maps_exactly():
    az = 2 * np.pi * np.arange(A) / A
    want = P.cartesian_sample_maps(az, B, RES_BIN, 0.0, GRID_RES, GRID_W)
    got = P.moving_sample_maps(az, np.zeros(A), None, None, B, RES_BIN, 0.0, GRID_RES, GRID_W)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


@pytest.mark.parametrize("twist", [(12.0, 0.0, 0.0), (10.0, 0.5, 0.4), (8.0, 0.0, -0.6)])
def test_deskew_puts_every_point_where_it_was_at_the_first_azimuth(twist):
    scan = skewed_scan(POINTS, twist)
    raw = P.polar_to_cartesian(scan, GRID_RES, GRID_W)
    fixed = P.polar_to_cartesian(scan, GRID_RES, GRID_W, twist=twist)
    skew_err = max(np.linalg.norm(peak_xy(raw, p, win=20) - p) for p in POINTS)
    for p in POINTS:
        # within a fraction of a 0.2 m pixel (the splats are one bin / one azimuth wide)
        assert np.linalg.norm(peak_xy(fixed, p) - p) < 0.12, (p, peak_xy(fixed, p))
    assert skew_err > 1.0  # the sweep as recorded is smeared by metres: the test can fail


def test_a_wrong_sign_of_the_velocity_makes_it_worse():
    twist = (10.0, 0.0, 0.4)
    scan = skewed_scan(POINTS, twist)
    right = P.polar_to_cartesian(scan, GRID_RES, GRID_W, twist=twist)
    wrong = P.polar_to_cartesian(scan, GRID_RES, GRID_W, twist=(10.0, 0.0, -0.4))
    p = POINTS[1]  # seen late in the sweep: the yaw's sign matters most there
    assert np.linalg.norm(peak_xy(wrong, p, win=20) - p) > 4 * np.linalg.norm(peak_xy(right, p) - p)


def test_frame_pose_draws_the_scene_in_the_moved_frame():
    scan = skewed_scan(POINTS, (0.0, 0.0, 0.0))
    frame = (3.0, -1.5, 0.2)  # the image's frame in the sensor frame
    img = P.polar_to_cartesian(scan, GRID_RES, GRID_W, frame_pose=frame)
    inv = invert(se2(*frame))
    for p in POINTS:
        want = inv[:2, :2] @ p + inv[:2, 2]
        assert np.linalg.norm(peak_xy(img, want) - want) < 0.12


def test_azimuth_times_of_invalid_rows_follow_their_neighbours():
    scan = skewed_scan(POINTS, (0.0, 0.0, 0.0))
    ts = scan.timestamps_us.copy()
    ts[5] = 0  # junk time of a dropped azimuth
    valid = np.ones(A, bool)
    valid[5] = False
    bad = RadarScan.from_arrays(ts, scan.azimuths_rad, scan.power, valid=valid, range_resolution_m=RES_BIN)
    t = P.azimuth_times_s(bad)
    np.testing.assert_allclose(t, (scan.timestamps_us - scan.timestamps_us[0]) * 1e-6, atol=2e-6)


# --------------------------------------------------------------------------- gap maths
def test_compose_residual_is_se2_composition_with_the_first_order_covariance():
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = rng.normal([0.3, -0.2, 0.02], [1.0, 1.0, 0.1])
        p = rng.normal([12.0, 1.0, 0.1], [3.0, 2.0, 0.1])
        pose, _ = compose_residual(m, np.eye(3), p)
        np.testing.assert_allclose(pose, to_xyyaw(se2(*m) @ se2(*p)), atol=1e-12)
    # covariance = J C Jᵀ: check J against finite differences
    m, p = np.array([0.5, 0.1, 0.05]), np.array([14.0, -2.0, 0.2])
    jac = np.zeros((3, 3))
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-6
        jac[:, i] = (compose_residual(m + d, np.eye(3), p)[0] - compose_residual(m - d, np.eye(3), p)[0]) / 2e-6
    c = np.diag([0.04, 0.09, 0.0004])
    np.testing.assert_allclose(compose_residual(m, c, p)[1], jac @ c @ jac.T, rtol=1e-6, atol=1e-12)
    # a yaw uncertainty swings the predicted 14 m sideways: y variance grows by 14² × σ_yaw²
    assert compose_residual(m, c, p)[1][1, 1] > 0.09 + 0.9 * 14.0**2 * 0.0004


def test_sweep_period_finds_gaps_after_three_intervals():
    sp = SweepPeriod()
    assert not sp.is_gap(10.0)  # no period yet
    for dt in (0.25, 0.25, 0.26):
        sp.observe(dt)
    assert sp.nominal_s == pytest.approx(0.25)
    assert not sp.is_gap(0.3) and sp.is_gap(0.5) and sp.is_gap(1.54)
    sp.observe(1.54)
    sp.observe(0.25)  # a long interval among ordinary ones does not move the median
    assert sp.nominal_s == pytest.approx(0.25)


# --------------------------------------------------------------------------- odometer
CELL = 1.6  # the tiny model's grid: 1.6 m cells, a ±2-cell (±3.2 m) window; an untrained raw
# model reads whole cells best, so the drives move by whole cells


def drive_poses(steps_x):
    """Sweeps seen from poses along +x, sweep k at ``sum(steps_x[:k])``, 0.25 s apart."""
    pts = world_points(0)
    xs = np.concatenate(([0.0], np.cumsum(steps_x)))
    return [render_scan(pts, se2(x, 0.0, 0.0), T0_US + k * PERIOD_US) for k, x in enumerate(xs)]


@pytest.mark.parametrize("prior", [True, False])
def test_gap_beyond_the_window_is_crossed_and_flagged(tiny_model, prior):
    # 1.6 m per sweep, then sweeps 6-8 dropped while the car speeds up: sweep 9 is 8.0 m past
    # sweep 5 (1 s later), where the constant-velocity prediction says 6.4 m
    scans = drive_poses([CELL] * 5 + [CELL, CELL, CELL, 2 * CELL] + [CELL] * 3)
    scans = [s for k, s in enumerate(scans) if k not in (6, 7, 8)]
    odo = RadarOdometer(tiny_model, motion_prior=prior)
    ests = [odo.step(s) for s in scans]
    gap = ests[6]
    assert GAP in gap.flags
    # the residual (1.6 m) is measured around the prediction; a plain match stops at 3.2 m
    assert gap.measurement[0] == pytest.approx(5 * CELL, abs=0.4)
    assert abs(gap.measurement[1]) < 0.4
    assert not any(GAP in e.flags for e in ests[1:6] + ests[7:])
    # the next ordinary step is matched against the gap sweep in its own frame
    assert ests[7].measurement[0] == pytest.approx(CELL, abs=0.4)
    assert odo.trajectory.poses[-1][0, 2] == pytest.approx(13 * CELL, abs=1.2)
    # the covariance is the residual's, carried through the composition: finite, positive
    assert np.all(np.linalg.eigvalsh(gap.measurement_covariance) > 0)


def test_a_plain_match_cannot_reach_that_far(tiny_model):
    """Why the window is centred: the same pair matched as it is stops at the window's edge."""
    scans = drive_poses([5 * CELL])
    odo = RadarOdometer(tiny_model, motion_prior=False)
    odo.step(scans[0])
    est = odo.step(scans[1])  # no period yet: no gap, no prediction
    assert GAP not in est.flags and est.pose[0] < 2 * CELL + 0.1


def test_max_gap_s_still_stops_the_stream(tiny_model):
    from radar_odom.errors import StreamError

    scans = drive_poses([CELL] * 8)
    scans = [s for k, s in enumerate(scans) if k not in (5, 6)]
    odo = RadarOdometer(tiny_model, max_gap_s=0.6)
    with pytest.raises(StreamError, match="max_gap_s"):
        for s in scans:
            odo.step(s)


def test_deskew_on_a_still_sensor_changes_nothing(tiny_model):
    scans = drive((0.0, 0.0, 0.0), 4)
    a = RadarOdometer(tiny_model, deskew=True)
    b = RadarOdometer(tiny_model, deskew=False)
    for s in scans:
        ea, eb = a.step(s), b.step(s)
        if ea is not None:
            np.testing.assert_allclose(ea.pose, eb.pose, atol=1e-6)


def test_deskew_is_refused_quietly_for_polar_models(tiny_polar_model):
    odo = RadarOdometer(tiny_polar_model, deskew=True)
    assert odo.deskew is False
    scans = drive((1.6, 0.0, 0.0), 3, geom=GEOM)
    assert [odo.step(s) is None for s in scans] == [True, False, False]


def test_deskew_must_be_a_bool(tiny_model):
    from radar_odom.errors import ConfigError

    with pytest.raises(ConfigError, match="deskew"):
        RadarOdometer(tiny_model, deskew="yes")


def test_unused_helpers_are_importable():
    # the render helpers come from test_odometer; keep the imports honest
    assert render_scan and world_points and PERIOD_US and T0_US
