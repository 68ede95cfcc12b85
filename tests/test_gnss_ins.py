"""RADIATE GNSS/INS reference (`radar_odom.io.gnss_ins`): reading, east-north-up, the INS
heading offset, poses at radar times in the Oxford convention, and the clock offset.

Synthetic ``GPS_IMU_Twist`` folders are written into tmp_path from a known trajectory (samples
listed twice, nanoseconds unpadded, as RADIATE publishes them); the real city drive (``real``
marker) is read from ``../shared/data/real/radiate-2019-02-12-edinburgh`` (never copied into the
repository).
"""
import math

import cv2
import numpy as np
import pytest

from radar_odom import SequenceError
from radar_odom.errors import ConfigError, GroundTruthWarning
from radar_odom.io import read_sequence
from radar_odom.io.gnss_ins import (
    ClockOffset,
    GnssInsTrack,
    enu_from_geodetic,
    estimate_clock_offset_s,
    estimate_heading_offset_rad,
    heading_offset_track_rad,
    poses_at,
    quaternion_yaw_rad,
    read_radiate_gnss_ins,
    relative_poses_at,
)
from radar_odom.se2 import relative_from_absolute, wrap_angle

ORIGIN = (55.939128728676749, -3.226737654901229, 117.0)  # the shared drive's first sample
WGS84_A_M, WGS84_F = 6378137.0, 1 / 298.257223563
E2 = WGS84_F * (2 - WGS84_F)
T0_US = 1549986597_000734  # GNSS/INS clock; .000734 s is printed as ".734000" (unpadded ns)
FINE_S = 0.001  # the known trajectory's step
SAMPLE_EVERY = 50  # fine steps per GNSS/INS sample: 20 Hz
GAP_S = (45.0, 45.85)  # samples dropped in here: a 0.9 s hole
INS_OFFSET_RAD = math.radians(-7.1)  # INS heading clockwise of the vehicle's axis, as measured
PITCH_RAD, ROLL_RAD = 0.02, -0.01


# ---------------------------------------------------------------- a known drive


def _cumulative(v: np.ndarray) -> np.ndarray:
    return np.r_[0.0, np.cumsum(0.5 * (v[1:] + v[:-1]) * FINE_S)]


@pytest.fixture(scope="module")
def drive():
    return make_drive()


def make_drive():
    """Every ms for 60 s: east, north (m) and the vehicle's ENU yaw (rad, unwrapped; the track
    direction: no crab). Starts heading north, speeds up to 6–10 m/s, turns right 90° at 10 s,
    left 60° at 25 s, right 45° at 38 s, left 90° at 50 s."""
    t = np.arange(0, 60_001) * FINE_S
    speed = np.minimum(t / 4, 1) * (8 + 2 * np.sin(0.4 * t))
    rate = np.zeros_like(t)
    for start, dur, turn in ((10, 5, -math.pi / 2), (25, 3, math.pi / 3), (38, 4, -math.pi / 4), (50, 3, math.pi / 2)):
        inside = (t >= start) & (t < start + dur)
        rate[inside] = turn / dur * (1 - np.cos(2 * math.pi * (t[inside] - start) / dur))
    yaw = math.pi / 2 + _cumulative(rate)
    return {"t": t, "east": _cumulative(speed * np.cos(yaw)), "north": _cumulative(speed * np.sin(yaw)), "yaw": yaw}


def _geodetic(east, north, up, origin=ORIGIN):
    """(lat °, lon °, height m) of ENU points: the inverse of the tangent plane, by iteration."""
    lat0, lon0 = math.radians(origin[0]), math.radians(origin[1])
    n0 = WGS84_A_M / math.sqrt(1 - E2 * math.sin(lat0) ** 2)
    x0 = np.array([(n0 + origin[2]) * math.cos(lat0) * math.cos(lon0),
                   (n0 + origin[2]) * math.cos(lat0) * math.sin(lon0),
                   (n0 * (1 - E2) + origin[2]) * math.sin(lat0)])
    sl, cl, sp, cp = math.sin(lon0), math.cos(lon0), math.sin(lat0), math.cos(lat0)
    rows = np.array([[-sl, cl, 0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])  # ECEF → ENU
    x, y, z = (x0[:, None] + rows.T @ np.vstack([east, north, up]))
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1 - E2))
    for _ in range(10):
        n = WGS84_A_M / np.sqrt(1 - E2 * np.sin(lat) ** 2)
        h = p / np.cos(lat) - n
        lat = np.arctan2(z, p * (1 - E2 * n / (n + h)))
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def _quaternion(yaw, pitch, roll):
    """float[M, 4] x, y, z, w of Rz(yaw)·Ry(pitch)·Rx(roll)."""
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    cp, sp, cr, sr = math.cos(pitch / 2), math.sin(pitch / 2), math.cos(roll / 2), math.sin(roll / 2)
    return np.stack([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy], axis=-1)


def _sample_text(lat, lon, alt, q) -> str:
    zeros = "0.000000000000000,0.000000000000000,0.000000000000000 \n"
    return (f"{lat:.15f},{lon:.15f},{alt:.15f} \n" + zeros * 3 + ",".join(f"{v:.8f}" for v in q) + " \n"
            + "0.00108,0.00002,0.00082 \n0.01444,0.02113,-0.06013 \n" + zeros * 9)


def sample_indices(drive, until_s=60.0) -> np.ndarray:
    """Fine-grid indices of the GNSS/INS samples: every 50 ms up to ``until_s``, none inside GAP_S."""
    idx = np.arange(0, len(drive["t"]), SAMPLE_EVERY)
    t = drive["t"][idx]
    return idx[((t < GAP_S[0]) | (t > GAP_S[1])) & (t <= until_s)]


def write_gnss(root, drive, *, listings=None, noise_m=0.0, seed=0, until_s=60.0):
    """SEQ/GPS_IMU_Twist.txt and SEQ/GPS_IMU_Twist/NNNNNN.txt; returns the sample indices.

    Each sample is listed ``listings[k]`` times (default twice), consecutive frames from 2009,
    identical times with unpadded nanoseconds; every copy gets its own (identical) file. Samples
    up to ``until_s`` (a short file is enough where only the reading is tested).
    """
    idx = sample_indices(drive, until_s)
    rng = np.random.default_rng(seed)
    east = drive["east"][idx] + rng.normal(0, noise_m, len(idx)) if noise_m else drive["east"][idx]
    north = drive["north"][idx] + rng.normal(0, noise_m, len(idx)) if noise_m else drive["north"][idx]
    lat, lon, alt = _geodetic(east, north, np.zeros(len(idx)))
    quats = _quaternion(drive["yaw"][idx] + INS_OFFSET_RAD, PITCH_RAD, ROLL_RAD)
    folder = root / "GPS_IMU_Twist"
    folder.mkdir(parents=True, exist_ok=True)
    lines, frame = [], 2009
    for k, i in enumerate(idx.tolist()):
        whole, ns = divmod((T0_US + i * 1000) * 1000, 10**9)
        text = _sample_text(lat[k], lon[k], alt[k], quats[k])
        for _ in range(2 if listings is None else listings[k]):
            (folder / f"{frame:06d}.txt").write_text(text)
            lines.append(f"Frame: {frame:06d} Time: {whole}.{ns}")
            frame += 1
    (root / "GPS_IMU_Twist.txt").write_text("\n".join(lines) + "\n")
    return idx


@pytest.fixture(scope="module")
def written(tmp_path_factory, drive):
    """(folder, sample indices, track) of a noise-free synthetic recording."""
    root = tmp_path_factory.mktemp("gnss")
    idx = write_gnss(root, drive)
    return root, idx, read_radiate_gnss_ins(root)


def truth_oxford_pose(drive, query_s):
    """Oxford pose (x, y, yaw) of the vehicle at each query time in its frame at time 0, worked
    out by hand: it starts heading north, so x = north, y (right) = east, and yaw (clockwise,
    z down) = −(change of the counter-clockwise ENU yaw)."""
    i = np.round(np.asarray(query_s) / FINE_S).astype(int)
    assert drive["yaw"][0] == math.pi / 2
    return np.stack([drive["north"][i] - drive["north"][0], drive["east"][i] - drive["east"][0],
                     -(drive["yaw"][i] - drive["yaw"][0])], axis=-1)


def truth_oxford_relative(drive, query_s):
    """Oxford (x, y, yaw) of query k+1 in query k: the ENU step turned into the frame at k."""
    i = np.round(np.asarray(query_s) / FINE_S).astype(int)
    d_e, d_n = np.diff(drive["east"][i]), np.diff(drive["north"][i])
    yaw = drive["yaw"][i][:-1]
    forward = np.cos(yaw) * d_e + np.sin(yaw) * d_n
    left = -np.sin(yaw) * d_e + np.cos(yaw) * d_n
    return np.stack([forward, -left, -np.diff(drive["yaw"][i])], axis=-1)


def us_at(query_s) -> np.ndarray:
    """int64 UNIX µs on the GNSS/INS clock of seconds after the first sample."""
    return T0_US + np.round(np.asarray(query_s) * 1e6).astype(np.int64)


# ---------------------------------------------------------------- reading


def test_reader_keeps_one_sample_per_time_with_unpadded_nanoseconds(tmp_path, drive):
    idx = sample_indices(drive, until_s=10.0)
    listings = [2] * len(idx)
    listings[3], listings[7], listings[10] = 1, 3, 4  # as in the real file: a few listed 1, 3 or 4 times
    write_gnss(tmp_path, drive, listings=listings, until_s=10.0)
    # the first file of a time is read: a broken later copy is never opened
    first_of_sample_4 = 2009 + sum(listings[:4])
    (tmp_path / "GPS_IMU_Twist" / f"{first_of_sample_4 + 1:06d}.txt").write_text("garbage\n")
    assert ".734000\n" in (tmp_path / "GPS_IMU_Twist.txt").read_text()  # unpadded: 734 000 ns
    track = read_radiate_gnss_ins(tmp_path)
    assert isinstance(track, GnssInsTrack) and len(track) == len(idx)
    np.testing.assert_array_equal(track.times_us, T0_US + idx * 1000)
    assert track.times_us.dtype == np.int64 and np.all(np.diff(track.times_us) > 0)
    np.testing.assert_allclose(track.east_m, drive["east"][idx] - drive["east"][0], atol=1e-6)
    np.testing.assert_allclose(track.north_m, drive["north"][idx] - drive["north"][0], atol=1e-6)
    np.testing.assert_allclose(track.up_m, 0.0, atol=1e-6)
    expected_heading = wrap_angle(drive["yaw"][idx] + INS_OFFSET_RAD)
    np.testing.assert_allclose(wrap_angle(track.heading_rad - expected_heading), 0.0, atol=1e-6)
    assert track.origin_deg_m == pytest.approx(ORIGIN, abs=1e-9)
    assert track.source == str(tmp_path / "GPS_IMU_Twist")


def test_no_folder_no_track(tmp_path, drive):
    write_gnss(tmp_path, drive, until_s=2.0)
    (tmp_path / "elsewhere").mkdir()
    assert read_radiate_gnss_ins(tmp_path / "elsewhere") is None
    # radiate-fog_6_0's form: the time file without the per-sample folder
    (tmp_path / "fog").mkdir()
    (tmp_path / "fog" / "GPS_IMU_Twist.txt").write_text((tmp_path / "GPS_IMU_Twist.txt").read_text())
    assert read_radiate_gnss_ins(tmp_path / "fog") is None


def test_enu_of_a_hand_computed_case():
    """Within 100 m the tangent plane is the radii-of-curvature form at the origin's height, plus
    the plane's drop from the surface: d² tan φ0 / 2N northwards along a parallel, d²/2R down."""
    lat0 = math.radians(ORIGIN[0])
    s = math.sin(lat0)
    m = WGS84_A_M * (1 - E2) / (1 - E2 * s * s) ** 1.5  # meridional radius of curvature
    n = WGS84_A_M / math.sqrt(1 - E2 * s * s)  # prime vertical
    h0 = ORIGIN[2]
    east, north, up = enu_from_geodetic(np.array([ORIGIN[0] + 0.0009]), np.array([ORIGIN[1]]),
                                        np.array([h0]), ORIGIN)
    d = (m + h0) * math.radians(0.0009)  # ≈ 100.2 m due north
    assert north[0] == pytest.approx(d, abs=2e-4) and abs(east[0]) < 1e-6
    assert up[0] == pytest.approx(-d * d / (2 * math.sqrt(m * n)), abs=1e-4)
    east, north, up = enu_from_geodetic(np.array([ORIGIN[0]]), np.array([ORIGIN[1] + 0.0015]),
                                        np.array([h0]), ORIGIN)
    d = (n + h0) * math.cos(lat0) * math.radians(0.0015)  # ≈ 93.7 m due east
    assert east[0] == pytest.approx(d, abs=2e-4)
    assert north[0] == pytest.approx(d * d * math.tan(lat0) / (2 * n), abs=1e-4)  # ≈ 1.0 mm
    assert up[0] == pytest.approx(-d * d / (2 * n), abs=1e-4)
    # the origin itself, and heights
    e, n_, u = enu_from_geodetic(np.array([ORIGIN[0]]), np.array([ORIGIN[1]]), np.array([h0 + 5.0]), ORIGIN)
    assert abs(e[0]) < 1e-9 and abs(n_[0]) < 1e-9 and u[0] == pytest.approx(5.0, abs=1e-9)


def test_quaternion_yaw_is_the_z_angle_of_z_y_x_euler():
    yaw = np.radians([0.0, 30.0, -100.0, 179.0])
    np.testing.assert_allclose(quaternion_yaw_rad(_quaternion(yaw, 0.0, 0.0)), yaw, atol=1e-12)
    np.testing.assert_allclose(quaternion_yaw_rad(_quaternion(yaw, 0.05, -0.03)), yaw, atol=1e-12)
    np.testing.assert_allclose(quaternion_yaw_rad(3.0 * _quaternion(yaw, 0.0, 0.0)), yaw, atol=1e-12)  # any norm
    assert quaternion_yaw_rad([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]) == pytest.approx(math.pi / 2)


# ---------------------------------------------------------------- heading offset


def test_heading_offset_is_recovered(tmp_path, drive):
    write_gnss(tmp_path, drive, noise_m=0.01)  # centimetre GNSS noise
    track = read_radiate_gnss_ins(tmp_path)
    offset, iqr, n = estimate_heading_offset_rad(track)
    assert math.degrees(offset) == pytest.approx(math.degrees(INS_OFFSET_RAD), abs=0.2)
    assert 0 <= math.degrees(iqr) < 1.0
    assert n > 300  # the straight stretches above 3 m/s, less the turns and the start
    # stricter speed: fewer samples, the same answer
    offset6, _, n6 = estimate_heading_offset_rad(track, min_speed_mps=7.0)
    assert n6 < n and math.degrees(offset6) == pytest.approx(math.degrees(INS_OFFSET_RAD), abs=0.2)


def test_heading_offset_needs_straight_driving_at_speed(written):
    _, _, track = written
    with pytest.raises(SequenceError, match=r"only 0 samples .* above 50\.0 m/s .*lower min_speed_mps"):
        estimate_heading_offset_rad(track, min_speed_mps=50.0)


# ---------------------------------------------------------------- poses


def test_poses_north_then_a_right_turn_in_the_oxford_convention(written, drive):
    _, _, track = written
    query_s = np.array([0.0, 5.0, 9.5, 12.5, 20.0, 30.0])
    poses = poses_at(track, us_at(query_s), heading_offset_rad=INS_OFFSET_RAD)
    assert poses.shape == (6, 3, 3)
    np.testing.assert_allclose(poses[0], np.eye(3), atol=1e-12)
    # 9.5 s: still heading north, straight ahead
    assert poses[2, 0, 2] > 40 and abs(poses[2, 1, 2]) < 1e-6
    # 20 s: after the 90° right turn, heading east: a right turn is positive yaw and moves to +y
    x, y, yaw = poses[4, 0, 2], poses[4, 1, 2], math.atan2(poses[4, 1, 0], poses[4, 0, 0])
    assert y > 20 and x > 40 and yaw == pytest.approx(math.pi / 2, abs=1e-3)
    # everywhere: the hand-worked pose (linear between 20 Hz samples: millimetres off in turns)
    expected = truth_oxford_pose(drive, query_s)
    got = np.stack([poses[:, 0, 2], poses[:, 1, 2], np.arctan2(poses[:, 1, 0], poses[:, 0, 0])], axis=-1)
    np.testing.assert_allclose(got[:, :2], expected[:, :2], atol=0.01)
    np.testing.assert_allclose(wrap_angle(got[:, 2] - expected[:, 2]), 0.0, atol=math.radians(0.05))


def test_uncorrected_heading_skews_the_poses_by_the_ins_offset(written, drive):
    _, _, track = written
    query_s = np.array([0.0, 9.0])
    raw = poses_at(track, us_at(query_s))  # INS axis, 7.1° clockwise of the track
    along = truth_oxford_pose(drive, query_s)[1, 0]
    # seen from a frame turned 7.1° clockwise, straight ahead lies 7.1° to the left: y < 0
    assert raw[1, 1, 2] == pytest.approx(-along * math.sin(-INS_OFFSET_RAD), abs=0.01)


def test_relative_poses_chain_to_the_absolute_ones(written, drive):
    _, _, track = written
    query_s = np.r_[np.arange(2.0, 44.0, 0.25), 45.4, np.arange(47.0, 58.0, 0.25)]
    times = us_at(query_s)
    rel = relative_poses_at(track, times, heading_offset_rad=INS_OFFSET_RAD)
    assert rel.shape == (len(times) - 1, 3)
    np.testing.assert_allclose(rel, relative_from_absolute(poses_at(track, times, 0.0, INS_OFFSET_RAD)), atol=1e-9)
    expected = truth_oxford_relative(drive, query_s)
    ok = np.isfinite(rel).all(axis=1)
    np.testing.assert_allclose(rel[ok, :2], expected[ok, :2], atol=0.01)
    np.testing.assert_allclose(rel[ok, 2], expected[ok, 2], atol=math.radians(0.05))
    # 45.4 s lies in the 0.9 s hole in the samples: only the two pairs it is in are unknown
    k = np.flatnonzero(query_s == 45.4)[0]
    assert not ok[k - 1] and not ok[k] and ok.sum() == len(ok) - 2


def test_clock_offset_shifts_the_query(written):
    _, _, track = written
    radar_us = us_at(np.arange(3.0, 30.0, 0.25)) - 1_700_000  # radar clock 1.7 s behind
    np.testing.assert_allclose(poses_at(track, radar_us, clock_offset_s=1.7), poses_at(track, radar_us + 1_700_000),
                               atol=1e-9)
    np.testing.assert_allclose(relative_poses_at(track, radar_us, 1.7), relative_poses_at(track, radar_us + 1_700_000),
                               atol=1e-9)


def test_unknown_poses_are_nan(written):
    _, _, track = written
    query_s = np.array([-1.0, 0.0, 45.4, 59.0, 60.5])  # before the track, in the hole, after it
    poses = poses_at(track, us_at(query_s))
    known = np.isfinite(poses).all(axis=(1, 2))
    assert known.tolist() == [False, True, False, True, False]
    np.testing.assert_allclose(poses[1], np.eye(3), atol=1e-12)  # the first known time is the origin
    assert np.isfinite(poses_at(track, us_at(query_s), max_sample_gap_s=1.0)[2]).all()  # a wider bridge
    rel = relative_poses_at(track, us_at(query_s))
    assert np.isnan(rel).all(axis=1).tolist() == [True, True, True, True]
    assert np.isnan(poses_at(track, us_at([-5.0, 70.0]))).all()  # nothing known: all NaN
    assert np.isnan(poses[[0, 2, 4]]).all()  # whole matrices
    with pytest.raises(ConfigError, match="integer array of UNIX µs"):
        poses_at(track, np.array([1.5e15]))


# ---------------------------------------------------------------- clock offset


def radar_pairs(drive, offset_s, seed=1, n_outliers=3):
    """Radar times (radar clock = GNSS/INS clock − offset) at ≈ 4 Hz over 8–43 s, one sweep
    dropped, and noisy per-pair estimates of the true relative poses: yaw σ 0.2°, distance σ 3 cm,
    a few gross failures and one missing estimate."""
    rng = np.random.default_rng(seed)
    query_s = np.arange(8.0, 43.0, 0.25) + rng.integers(-3, 4, 140) * FINE_S  # ms jitter
    query_s = np.delete(query_s, 60)
    est = truth_oxford_relative(drive, query_s)
    est[:, :2] += rng.normal(0, 0.03 / math.sqrt(2), (len(est), 2))
    est[:, 2] += rng.normal(0, math.radians(0.2), len(est))
    bad = rng.choice(len(est), n_outliers, replace=False)
    est[bad] += [2.0, 1.0, 0.2]
    est[5] = np.nan
    return us_at(query_s) - int(round(offset_s * 1e6)), est


@pytest.mark.parametrize("offset_s", [1.7, -63.8])
def test_clock_offset_is_recovered_from_noisy_estimates(written, drive, offset_s):
    _, _, track = written
    radar_us, est = radar_pairs(drive, offset_s)
    found = estimate_clock_offset_s(track, radar_us, est)
    assert isinstance(found, ClockOffset)
    assert found.offset_s == pytest.approx(offset_s, abs=0.02)
    # the default search: wherever ≥ 80 % of the pairs fall in the track, not a fixed ± few s
    lo, hi = found.search_s
    assert lo < offset_s - 5 and hi > offset_s + 5
    assert found.grid_s[0] == pytest.approx(lo) and len(found.grid_s) == len(found.grid_cost)
    assert found.num_pairs >= len(est) - 3  # the NaN estimate and the pair across the hole are left out
    assert found.second_best_ratio > 2.0 and found.cost < 0.3  # the outliers cost most
    # the heading offset does not enter the cost; a given search range is kept
    again = estimate_clock_offset_s(track, radar_us, est, heading_offset_rad=INS_OFFSET_RAD,
                                    search_s=(offset_s - 1.0, offset_s + 1.0))
    assert again.offset_s == pytest.approx(found.offset_s, abs=1e-9) and again.search_s == (offset_s - 1, offset_s + 1)


def test_clock_offset_bad_input(written, drive):
    _, _, track = written
    radar_us, est = radar_pairs(drive, 1.7)
    with pytest.raises(ConfigError, match=r"est_relative must be float\[N−1, 3\]"):
        estimate_clock_offset_s(track, radar_us, est[:-1])
    with pytest.raises(SequenceError, match="only 0 radar estimates are finite"):
        estimate_clock_offset_s(track, radar_us, np.full_like(est, np.nan))
    with pytest.raises(ConfigError, match="search_s must be"):
        estimate_clock_offset_s(track, radar_us, est, search_s=(2.0, 1.0))
    with pytest.raises(SequenceError, match="no offset in .* lets 10 radar pairs"):
        estimate_clock_offset_s(track, radar_us, est, search_s=(500.0, 501.0))
    long_radar = us_at(np.arange(0, 200, 0.25))  # 200 s of radar against a 60 s track
    with pytest.raises(SequenceError, match="too short to hold 80%"):
        estimate_clock_offset_s(track, long_radar, np.zeros((len(long_radar) - 1, 3)))


# ---------------------------------------------------------------- bad folders


def _lines_of(root):
    return (root / "GPS_IMU_Twist.txt").read_text().splitlines()


def _restore(root, lines):
    (root / "GPS_IMU_Twist.txt").write_text("\n".join(lines) + "\n")
    return root


def test_missing_or_garbled_sample_files_are_skipped_with_a_count(tmp_path, drive):
    """One unreadable sample costs that sample (a warning names it and counts them), not the track."""
    write_gnss(tmp_path, drive, until_s=2.0)
    whole = len(read_radiate_gnss_ins(tmp_path))
    sample = tmp_path / "GPS_IMU_Twist" / "002011.txt"  # the second sample, listed on line 3
    good = sample.read_text()
    sample.unlink()
    with pytest.warns(GroundTruthWarning, match=r"1 of \d+ samples cannot be read and are skipped \(the first: .*"
                                                r"002011\.txt: no such file, but it is listed on line 3 of"):
        assert len(read_radiate_gnss_ins(tmp_path)) == whole - 1
    for text, match in [
        ("55.9,abc,117\n" + good.split("\n", 1)[1], r"002011\.txt, line 1: expected 3 comma-separated numbers "
                                                    r"\(latitude, longitude, altitude\), got '55\.9,abc,117'"),
        ("\n".join(good.splitlines()[:4] + ["0.1,0.2,0.3"] + good.splitlines()[5:]),
         r"002011\.txt, line 5: expected 4 comma-separated numbers \(the orientation quaternion"),
        ("\n".join(good.splitlines()[:2]), r"line 5: .* got nothing \(the file ends\)"),
        ("", r"line 1: .* got nothing \(the file ends\)"),
        ("\n".join(["95.0,-3.2,117"] + good.splitlines()[1:]), r"line 1: latitude 95\.0, longitude -3\.2 are not"),
        ("\n".join(good.splitlines()[:4] + ["0,0,0,0"] + good.splitlines()[5:]), r"line 5: .* is not a rotation"),
        ("\n".join(good.splitlines()[:4] + ["nan,0,0,1"] + good.splitlines()[5:]), r"line 5: expected 4"),
        ("\n".join(["nan,-3.2,117"] + good.splitlines()[1:]), r"line 1: expected 3 comma-separated numbers"),
        # a fix at (0, 0) was taken and the track jumped thousands of km
        ("\n".join(["0.0,0.0,0.0"] + good.splitlines()[1:]), r"line 1: latitude and longitude are exactly 0"),
    ]:
        sample.write_text(text)
        with pytest.warns(GroundTruthWarning, match=match) as record:
            track = read_radiate_gnss_ins(tmp_path)
        assert len(track) == whole - 1 and "listed on line 3" in str(record[0].message)
        assert np.all(np.isfinite(track.east_m)) and np.all(np.isfinite(track.heading_rad))
    # most samples unreadable: the track is not used, and the error says why
    for path in sorted((tmp_path / "GPS_IMU_Twist").glob("*.txt"))[: 3 * whole // 2]:
        path.write_text("garbage\n")
    with pytest.raises(SequenceError, match=r"GNSS/INS samples cannot be read, too many to use the track"):
        read_radiate_gnss_ins(tmp_path)


def test_bad_time_files(tmp_path, drive):
    write_gnss(tmp_path, drive, until_s=2.0)
    lines = _lines_of(tmp_path)
    (tmp_path / "GPS_IMU_Twist.txt").unlink()
    with pytest.raises(SequenceError, match=r"GPS_IMU_Twist\.txt: no such file"):
        read_radiate_gnss_ins(tmp_path)
    # the clock stepping back once (a receiver re-sync): read on, the overlap dropped, a warning
    whole = len(read_radiate_gnss_ins(_restore(tmp_path, lines)))
    backwards = lines[:6] + [lines[6].replace("Time: 1549986597.", "Time: 1549986596.")] + lines[7:]
    (tmp_path / "GPS_IMU_Twist.txt").write_text("\n".join(backwards) + "\n")
    with pytest.warns(GroundTruthWarning, match=r"the clock steps back 0\.950 s at line 7 of GPS_IMU_Twist\.txt "
                                               r"\(frame 2015\); the 1 sample\(s\) that repeat time already covered"):
        track = read_radiate_gnss_ins(tmp_path)
    # (line 7 re-lists the sample of line 6: dropping its stepped-back time loses no sample)
    assert len(track) == whole and np.all(np.diff(track.times_us) > 0)
    # going back again and again is a corrupt file, not a re-sync: the error names where
    many = [ln.replace("Time: 1549986597.", "Time: 1549986596.") if k % 4 == 2 else ln for k, ln in enumerate(lines)]
    (tmp_path / "GPS_IMU_Twist.txt").write_text("\n".join(many) + "\n")
    with pytest.raises(SequenceError) as err:
        read_radiate_gnss_ins(tmp_path)
    assert "GPS_IMU_Twist.txt, line" in str(err.value) and "is before frame" in str(err.value)
    (tmp_path / "GPS_IMU_Twist.txt").write_text("\n".join(lines[:2]) + "\n")  # one sample, twice
    with pytest.raises(SequenceError, match="lists 1 distinct sample time"):
        read_radiate_gnss_ins(tmp_path)


# ---------------------------------------------------------------- the sequence


def test_a_radiate_sequence_carries_its_reference(tmp_path, drive):
    polar = tmp_path / "Navtech_Polar"
    polar.mkdir()
    for frame in (1, 2):
        assert cv2.imwrite(str(polar / f"{frame:06d}.png"), np.zeros((576, 400), np.uint8))
    (tmp_path / "Navtech_Polar.txt").write_text(
        "Frame: 000001 Time: 1549986597.5\nFrame: 000002 Time: 1549986597.75\n")
    seq = read_sequence(tmp_path)
    assert seq.reference is None and seq.gt_relative is None  # no GPS_IMU_Twist/ folder
    write_gnss(tmp_path, drive, until_s=2.0)
    seq = read_sequence(tmp_path)
    assert isinstance(seq.reference, GnssInsTrack) and len(seq.reference) == len(sample_indices(drive, 2.0))
    assert seq.reference is seq.reference  # read once
    assert seq.gt_relative is None  # its clock is not the radar's: no ground truth until aligned


# ---------------------------------------------------------------- the real drive


@pytest.fixture(scope="module")
def edinburgh(real_data_dir):
    path = real_data_dir / "radiate-2019-02-12-edinburgh"
    if not (path / "GPS_IMU_Twist").is_dir():
        pytest.skip(f"no RADIATE city drive with GNSS/INS samples at {path}")
    return path


@pytest.fixture(scope="module")
def real_track(edinburgh):
    return read_radiate_gnss_ins(edinburgh)


@pytest.mark.real
def test_real_track_reads_at_20_hz(real_track, real_data_dir):
    assert len(real_track) == 1434  # 2867 listings
    spacing_s = np.diff(real_track.times_us) / 1e6
    assert np.median(spacing_s) == pytest.approx(0.05, abs=0.001) and spacing_s.max() < 1.0
    assert real_track.times_us[0] == 1549986597200734  # "Time: 1549986597.200734000"
    assert np.all(np.isfinite(real_track.east_m)) and np.abs(real_track.up_m).max() < 20
    # radiate-fog_6_0 has only the time file (its samples even run backwards once): no track
    assert read_radiate_gnss_ins(real_data_dir / "radiate-fog_6_0") is None


@pytest.mark.real
def test_real_ins_heading_is_clockwise_of_the_track(real_track):
    offset, iqr, n = estimate_heading_offset_rad(real_track)
    # measured: −7.50°, interquartile range 1.03° wide, 398 samples (README of the data: −7.1°)
    assert math.degrees(offset) == pytest.approx(-7.1, abs=1.0)
    assert math.degrees(iqr) < 3.0 and n > 200


@pytest.mark.real
def test_real_reference_over_the_radar_frames(real_track, edinburgh):
    seq = read_sequence(edinburgh)
    offset, _, _ = estimate_heading_offset_rad(real_track)
    # two holes of 0.6 s and 0.8 s in the samples lie under the radar's frames: bridged here
    poses = poses_at(real_track, seq.timestamps_us, 1.7, offset, max_sample_gap_s=1.0)
    assert np.isfinite(poses).all()
    path_m = np.hypot(*np.diff(poses[:, :2, 2], axis=0).T).sum()
    assert path_m == pytest.approx(445, abs=5)
    assert 1 <= np.isnan(poses_at(real_track, seq.timestamps_us, 1.7, offset)[:, 0, 0]).sum() <= 10  # 0.5 s default
    # with the heading on the track, steps go forward; left on the INS axis they gain a sideways part
    rel = relative_poses_at(real_track, seq.timestamps_us, 1.7, offset)
    raw = relative_poses_at(real_track, seq.timestamps_us, 1.7)
    moving = np.isfinite(rel).all(axis=1) & (rel[:, 0] > 0.5)
    assert np.abs(rel[moving, 1]).sum() / rel[moving, 0].sum() < 0.06
    assert np.abs(raw[moving, 1]).sum() / raw[moving, 0].sum() > 0.1


@pytest.mark.slow
@pytest.mark.real
def test_real_clock_offset_from_the_radars_own_odometry(real_track, edinburgh):
    import radar_odom
    from radar_odom import RadarOdometer

    if "cart-0.4" not in radar_odom.pretrained_names():
        pytest.skip("no shipped cart-0.4 model in this checkout")
    seq = read_sequence(edinburgh)
    odo = RadarOdometer(radar_odom.pretrained("cart-0.4"), max_gap_s=2.0)
    est = np.full((len(seq) - 1, 3), np.nan)
    for frame in seq:
        step = odo.step(frame.scan)
        if frame.index > 0 and step is not None:
            est[frame.index - 1] = step.pose
    found = estimate_clock_offset_s(real_track, seq.timestamps_us, est)
    # measured: +1.644 s (yaw alone 1.63 s, distance alone 1.70 s), 272 pairs; README: ≈ +1.7 s
    assert found.offset_s == pytest.approx(1.7, abs=0.1)
    assert found.num_pairs > 250 and found.second_best_ratio > 2.0


# ---------------------------------------------------------------- heading offset followed in time


def test_a_stepping_ins_offset_is_followed(drive):
    """The INS re-aligns mid-drive (−7.1° → −1.0° at 30 s, as on the full shared drive): the offset
    followed in time recovers both levels, so the reference heading stays on the vehicle's axis,
    where one constant leaves several degrees of error on one side of the step."""
    idx = sample_indices(drive)
    t = drive["t"][idx]
    step = np.where(t < 30.0, INS_OFFSET_RAD, math.radians(-1.0))
    start = 1549986597_000_000
    track = GnssInsTrack(times_us=start + np.round(t * 1e6).astype(np.int64), east_m=drive["east"][idx],
                         north_m=drive["north"][idx], up_m=np.zeros(len(idx)),
                         heading_rad=wrap_angle(drive["yaw"][idx] + step))
    followed = heading_offset_track_rad(track)
    away = np.abs(t - 30.0) > 6.0
    np.testing.assert_allclose(np.degrees(followed[away]), np.degrees(step[away]), atol=0.2)
    # radar times every 0.25 s: the vehicle's heading, not the INS's, with the followed offset
    radar_us = start + np.arange(4, 236) * 250_000
    truth_yaw = np.interp((radar_us - start) / 1e6, drive["t"], drive["yaw"])
    for offset, worst in ((followed, 0.3), (float(np.median(followed)), 2.0)):
        poses = poses_at(track, radar_us, 0.0, offset, max_sample_gap_s=1.0)
        yaw = -np.arctan2(poses[:, 1, 0], poses[:, 0, 0])  # Oxford yaw is clockwise: back to ENU
        err = np.degrees(wrap_angle(yaw - (truth_yaw - truth_yaw[0])))
        assert (np.abs(err[np.abs((radar_us - start) / 1e6 - 30.0) > 6.0]).max() < 0.3) == (worst < 1.0)
    with pytest.raises(ConfigError, match="one offset or one per track sample"):
        poses_at(track, radar_us, 0.0, followed[:-1])
