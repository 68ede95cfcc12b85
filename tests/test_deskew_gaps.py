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
from radar_odom.odometry import gaps as G
from radar_odom.odometry.gaps import GAP, compose_residual
from radar_odom.odometry.motion_prior import GATED
from radar_odom.odometry.odometer import RadarOdometer
from radar_odom.odometry.stream_time import StreamClock
from radar_odom.scan import RadarScan
from radar_odom.se2 import invert, se2, to_xyyaw, wrap_angle

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


@pytest.mark.parametrize("yaw", [-0.4, -0.1, 0.0, 0.15, 0.35])
def test_compose_residual_matches_the_matrix_product_in_turns(yaw):
    # from the maths: T = se2(M) · se2(P), with the prediction turning (a 13° bend over a gap is 0.23 rad)
    m = np.array([-0.3, 0.4, 0.6 * yaw])
    p = np.array([10.5, -2.1, yaw])
    pose, _ = compose_residual(m, np.eye(3), p)
    ref = se2(*m) @ se2(*p)
    np.testing.assert_allclose(se2(*pose), ref, atol=1e-12)
    # and the inverse: drawing at P and measuring the exact residual M = T·P⁻¹ gives T back
    t = np.array([10.5, -2.1, -0.236])
    exact = to_xyyaw(se2(*t) @ invert(se2(*p)))
    np.testing.assert_allclose(compose_residual(exact, np.eye(3), p)[0], t, atol=1e-12)


def test_crossing_prior_is_the_step_repeated_along_an_arc():
    step = np.array([1.53, -0.03, math.radians(-1.9)])  # one 0.25 s sweep of a steady bend
    cov = np.diag([0.01, 0.01, 1e-5])
    for k in (2, 4, 7, 9):
        pose, _ = G.crossing_prior(step, cov, 0.25, 0.25 * k)
        np.testing.assert_allclose(se2(*pose), np.linalg.matrix_power(se2(*step), k), atol=1e-9)
    # the old straight scaling puts a 7-period crossing of a 13.3° bend ~0.6 m to the bend's outside
    arc, _ = G.crossing_prior(step, cov, 0.25, 1.75)
    assert abs(arc[1] - 7 * step[1]) > 0.5 and arc[1] < 7 * step[1]


def test_crossing_prior_covariance_grows_with_the_gap():
    step, cov = np.array([2.0, 0.0, 0.02]), np.diag([0.01, 0.004, 1e-5])
    sds = [np.sqrt(np.diag(G.crossing_prior(step, cov, 0.25, 0.25 * k)[1])) for k in (2, 3, 5, 7, 9)]
    assert all(np.all(b > a) for a, b in zip(sds, sds[1:]))
    # a 7-period gap: about ½·a·t² of the sustained accelerations, not the per-step figures' 7 m and 70°
    sd7 = sds[3]
    assert 1.5 < sd7[0] < 4.0 and 1.0 < sd7[1] < 3.0 and math.radians(8) < sd7[2] < math.radians(25)
    # a later start (sweeps gated before the gap) is less certain too
    late = G.crossing_prior(step, cov, 0.25, 1.75, lead_s=0.5)[1]
    assert late[0, 0] > G.crossing_prior(step, cov, 0.25, 1.75)[1][0, 0]
    with pytest.raises(ValueError, match="positive"):
        G.crossing_prior(step, cov, 0.0, 1.0)


def test_window_edge_and_the_gate_against_the_gap_prior():
    assert not G.at_window_edge([6.0, -3.0, 0.2], 8.0, math.radians(15))
    assert G.at_window_edge([-7.2, 0.0, 0.0], 8.0, math.radians(15))
    assert G.at_window_edge([0.0, 0.0, math.radians(14)], 8.0, math.radians(15))
    prior = (np.array([10.0, 0.0, 0.0]), np.diag([2.0**2, 1.5**2, math.radians(10) ** 2]))
    tight = np.diag([0.04, 0.04, 1e-4])
    assert G.crossing_d2([10.5, 0.3, 0.05], tight, *prior) < 1.0
    # 8 m short and 40° off is far beyond the gap's prior: d² well over the χ² gate (16.3)
    assert G.crossing_d2([2.0, 0.0, math.radians(40)], tight, *prior) > 20.0
    # the yaw innovation is wrapped: 359° is −1°
    assert G.crossing_d2([10.0, 0.0, math.radians(359)], tight, *prior) < 0.1


def test_consensus_takes_the_largest_sharp_group_nearest_the_prior():
    sharp, blurry = np.diag([0.16, 0.09, 1e-4]), np.diag([4.0, 0.3, 1e-3])
    right = [np.array([10.45, -1.2, -0.238]), np.array([10.4, -1.25, -0.236])]
    alias = [np.array([5.8, -0.3, -0.065]), np.array([5.7, -0.4, -0.064])]
    prior = (np.array([10.7, -0.8, -0.14]), np.diag([9.0, 3.4, 0.07]))
    # two self-consistent readings of one size: the one the vehicle's motion makes likelier
    pose, _, members = G.consensus(alias + right, [sharp] * 4, prior=prior)
    assert members == [2, 3] and pose[0] == pytest.approx(10.45)  # the first member's (nearest centre)
    # a blurry alias does not count, however many centres find it
    pose, cov, members = G.consensus(alias * 2 + right, [blurry] * 4 + [sharp] * 2, max_sd_m=0.8)
    assert members == [4, 5]
    assert cov[0, 0] >= sharp[0, 0]  # the members' mean plus their spread, never tighter than one
    # one crossing alone, or none that agree: no consensus
    assert G.consensus(right[:1], [sharp]) is None
    assert G.consensus([right[0], alias[0]], [sharp, sharp]) is None
    assert G.consensus([], []) is None


def test_crossing_velocity_moves_by_the_pose_over_the_interval():
    # a 7-period crossing of a 13° bend: the constant velocity that ends there, from the maths (se2_exp)
    pose = np.array([10.4, -1.2, math.radians(-13.3)])
    v = G.crossing_velocity(pose, 1.75)
    np.testing.assert_allclose(G.se2_exp(v * 1.75), pose, atol=1e-12)
    assert v[2] == pytest.approx(math.radians(-13.3) / 1.75)
    # on a straight road it is the chord over the time
    np.testing.assert_allclose(G.crossing_velocity([5.0, 0.0, 0.0], 0.5), [10.0, 0.0, 0.0], atol=1e-12)


def test_poses_agree_within_both_tolerances_and_across_the_yaw_wrap():
    a = np.array([1.0, 2.0, math.pi - 0.005])
    assert G.poses_agree(a, [1.3, 2.4, -math.pi + 0.005], 0.5, 0.02)  # 0.5 m apart, 0.01 rad across ±π
    assert not G.poses_agree(a, [1.31, 2.4, math.pi - 0.005], 0.5, 0.02)
    assert not G.poses_agree(a, [1.0, 2.0, math.pi - 0.03], 0.5, 0.02)


@pytest.mark.parametrize("yaw_deg", [-40.0, -13.0, 0.0, 5.0, 30.0])
@pytest.mark.parametrize("chord_m", [-4.0, 2.0, 12.0])
def test_a_circular_arc_ends_on_its_half_yaw_chord(yaw_deg, chord_m):
    """A rear axle on a circle: the pose after turning by θ along an arc of curvature κ is
    (sin θ / κ, (1 − cos θ) / κ, θ), which lies on the line at θ/2: offset zero, whatever the radius, and
    forward or reversing; the offset's gradient is the finite difference's."""
    th = math.radians(yaw_deg)
    pose = np.array([chord_m * math.cos(th / 2), chord_m * math.sin(th / 2), th])  # a chord at θ/2 is an arc
    off, grad = G.arc_offset(pose)
    assert abs(off) < 1e-12
    assert not G.off_the_arc(pose, np.zeros((3, 3)))
    eps = 1e-6
    num = [(G.arc_offset(pose + eps * e)[0] - G.arc_offset(pose - eps * e)[0]) / (2 * eps) for e in np.eye(3)]
    np.testing.assert_allclose(grad, num, atol=1e-6)
    # a point 1 m to the +y side of the chord's end: offset +1 (measured across the chord)
    side = pose + np.array([-math.sin(th / 2), math.cos(th / 2), 0.0])
    assert G.arc_offset(side)[0] == pytest.approx(1.0)


def test_off_the_arc_allows_the_lever_arm_a_tightening_turn_and_the_reading_sigma():
    """Hand-computed: (10 m, 0, 0) with a sideways offset d is off the arc beyond `ARC_BASE_M` (0.5 m); turned
    by 0.2 rad the allowance is 0.5 + (2.5 + 0.25 · x) · 0.2; the reading's own σ widens it by 3 σ. The two
    readings of the simulated tightening turn (seed 10001, cart-0.4, 6 sweeps dropped): the truth is on it, the
    wrong peak the graph agreed on is 4 m off."""
    zero = np.zeros((3, 3))
    assert not G.off_the_arc([10.0, 0.49, 0.0], zero) and G.off_the_arc([10.0, 0.51, 0.0], zero)
    x, th = 10.0, 0.2
    allowed = 0.5 + (2.5 + 0.25 * x) * th
    on_chord = np.array([x, x * math.tan(th / 2), th])
    normal = np.array([-math.sin(th / 2), math.cos(th / 2), 0.0])
    assert not G.off_the_arc(on_chord + 0.99 * allowed * normal, zero)
    assert G.off_the_arc(on_chord + 1.01 * allowed * normal, zero)
    assert G.off_the_arc(on_chord - 1.01 * allowed * normal, zero)  # either side
    cov = np.diag([0.0, 0.1**2, 0.0])  # σ 0.1 m sideways: 0.3 m more allowed (cos(th/2) of it, to first order)
    assert not G.off_the_arc(on_chord + (allowed + 0.25) * normal, cov)
    assert G.off_the_arc(on_chord + (allowed + 0.35) * normal, cov)
    assert not G.off_the_arc([10.554, -1.350, math.radians(-16.0)], zero)  # the truth of that turn: 0.13 m
    assert G.off_the_arc([5.427, 4.254, math.radians(4.72)], np.diag([0.30, 0.24, 0.012]) ** 2)  # 4.0 m


def test_the_stream_clock_reads_whole_periods_after_three_one_period_intervals():
    clock = StreamClock()
    assert clock.periods(10.0) == 1  # no period yet: every interval one period
    for dt in (0.25, 0.25, 0.26):
        clock.observe(dt, 1)
    assert clock.period_s == pytest.approx(0.25)
    assert [clock.periods(t) for t in (0.3, 0.5, 1.54)] == [1, 2, 6]
    clock.observe(1.54, 6)  # a gap's interval does not move the period
    clock.observe(0.25, 1)
    assert clock.period_s == pytest.approx(0.25)
    for _ in range(15):  # a host's catch-up run at 0.9 of the period: the period follows it
        clock.observe(0.225, 1)
    assert clock.period_s == pytest.approx(0.225)
    assert StreamClock(known_s=0.25).periods(0.5) == 2  # a known period, before any interval


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


def test_a_stop_hidden_in_a_gap_is_read_by_the_match_not_replaced_by_the_prediction(tiny_model):
    # 1.6 m per sweep, then the car stops while 3 or 5 sweeps are dropped: the sweep after the gap is where the
    # last one before it was, 6.4 m or 9.6 m behind the arc prediction. The match reads the stop (one period's
    # motion at most, what the prior lets it fuse toward); the prediction (issue 50: "a gap prediction never
    # replaces a sharp match without evidence") would be metres off
    for dropped in (3, 5):
        scans = drive_poses([CELL] * 5 + [0.0] * (dropped + 1) + [0.0] * 2)
        scans = [s for k, s in enumerate(scans) if not 5 < k <= 5 + dropped]
        odo = RadarOdometer(tiny_model)
        ests = [odo.step(s) for s in scans]
        gap = ests[6]
        assert abs(gap.measurement[0]) < 0.4  # the graph's own reading: standing still
        assert gap.pose[0] < CELL and abs(gap.pose[0]) < CELL * (dropped + 1) - 3.0
        assert np.all(np.isfinite(gap.covariance)) and np.all(np.linalg.eigvalsh(gap.covariance) > 0)
        assert abs(odo.trajectory.poses[-1][0, 2] - 5 * CELL) < 2.0  # the trajectory ends near the stop


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


def test_deskew_is_refused_in_one_line_for_polar_models(tiny_polar_model):
    from radar_odom.errors import ConfigError

    for option in ("deskew", "centre_yaw"):  # issue 51: an option that cannot apply is refused, never dropped
        with pytest.raises(ConfigError, match="cannot be de-skewed or drawn turned"):
            RadarOdometer(tiny_polar_model, **{option: True})
    odo = RadarOdometer(tiny_polar_model)
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


# --------------------------------------------------------------------------- shipped models, simulated turns
def _bend_drive(seed, frames, rate_deg, speed_mps, ramp_m=None):
    from dataclasses import replace

    from radar_odom.se2 import chain_relative
    from radar_odom.sim.scenarios import get_scenario
    from radar_odom.sim.simulator import simulate_drive

    base = get_scenario("urban")
    drive_cfg = replace(base.drive, constant_speed_mps=speed_mps,
                        constant_curvature_per_m=math.radians(rate_deg) / (speed_mps * 0.25))
    if ramp_m is not None:
        drive_cfg = replace(drive_cfg, curvature_ramp_m=ramp_m)
    frames_ = list(simulate_drive(seed, frames, replace(base, drive=drive_cfg)))
    return [f.scan for f in frames_], chain_relative(np.array([f.pose_rel for f in frames_[1:]]))


def _crossing_error(model, scans, poses, before, dropped):
    odo = RadarOdometer(model)
    after = before + dropped + 1
    ests = [odo.step(scans[i]) for i in list(range(before - 5, before + 1)) + [after, after + 1]]
    gap = ests[6]
    assert GAP in gap.flags and not any(GAP in e.flags for e in ests[1:6] + ests[7:])
    truth = to_xyyaw(invert(poses[before]) @ poses[after])
    return gap, math.hypot(*(gap.pose[:2] - truth[:2])), abs(math.degrees(wrap_angle(gap.pose[2] - truth[2])))


@pytest.mark.slow
def test_six_dropped_sweeps_in_a_simulated_turn_are_crossed_within_the_issue_bounds():
    """Issue 41's done criterion: a 6-sweep gap in a 13° turn (7 periods at 1.9°/sweep, 6.1 m/s: 10.6 m)
    crossed within 0.3 m and 0.5° — here at five places along the bend: every one within 0.3 m, the
    yaw within 0.5° in the median and 1° at worst (as recorded, the crossing de-skew removed with issue 50:
    0.06-0.17 m; the worst yaw is the graph's own precision over a 10 m baseline, its reported σ ≈ 0.9°)."""
    import radar_odom

    scans, poses = _bend_drive(10000, 22, -13.3 / 7, 6.1)
    errors = []
    for before in (9, 10, 11, 12, 13):
        gap, t_err, yaw_err = _crossing_error(radar_odom.pretrained("cart-0.4"), scans, poses, before, 6)
        assert GATED not in gap.flags
        errors.append((t_err, yaw_err))
    t, yaw = np.array(errors).T
    assert t.max() < 0.3 and np.median(yaw) < 0.5 and yaw.max() < 1.0, errors


@pytest.mark.slow
def test_a_tightening_turn_the_graph_misreads_is_gated_to_the_prior():
    """Where the graph over 6 dropped sweeps locks onto a wrong peak even centred on the truth (a
    tightening turn, seed 10001, docs/gaps.md), the crossing keeps the arc prediction, flagged, within
    its covariance — not the 7 m and 15° the single match read. The cart-0.4 shipped in the fourth
    session of 2026-12-05 reads it (5.4 m, +4.3 m, +4.7°) from agreeing readings inside the gap's prior
    (truth 10.6 m, −1.3 m, −16°): 4 m sideways of the arc a car drives with that yaw, so the arc check
    (`gaps.off_the_arc`) leaves those readings out."""
    import radar_odom

    scans, poses = _bend_drive(10001, 20, -3.0, 6.1, ramp_m=30.0)
    gap, t_err, yaw_err = _crossing_error(radar_odom.pretrained("cart-0.4"), scans, poses, 10, 6)
    assert GATED in gap.flags
    assert t_err < 1.5 and yaw_err < 10.0, (t_err, yaw_err)
    sd = np.sqrt(np.diag(gap.covariance))
    assert t_err < 3 * math.hypot(sd[0], sd[1]) and math.radians(yaw_err) < 3 * sd[2]
