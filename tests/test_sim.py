"""The synthetic radar world: geometry of returns, motion distortion, labels, the Oxford layout
on disk, determinism and scenarios. Most tests use a short-range sensor (fewer bins) for speed;
`test_full_resolution_sweep_and_cli` runs the default CTS350-X geometry end to end."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from radar_odom.io import read_sequence
from radar_odom.polar import polar_to_cartesian
from radar_odom.se2 import chain_relative
from radar_odom.sim import (
    SCENARIOS,
    ArtefactConfig,
    DriveConfig,
    Scenario,
    SensorConfig,
    SimConfig,
    SimConfigError,
    Simulator,
    TrafficConfig,
    WorldConfig,
    simulate_drive,
    write_drive,
)
from radar_odom.sim.sensor import candidate_rows, ray_pair_hits, ray_segment_hits
from radar_odom.sim.traffic import box_corners_batch

RES = 0.0432
D_AZ = 2 * np.pi / 400
SHORT = SimConfig().with_sensor(num_bins=1200)  # 51.8 m instead of 162.8 m
NO_TRAFFIC = TrafficConfig(
    oncoming_per_km=0.0, followers_ahead=0, followers_behind=0, pedestrians_per_100m=0.0,
    cyclists_per_km=0.0, crossing_per_intersection=(0.0, 0.0),
)
CLEAN = SimConfig(sensor=SensorConfig(num_bins=1200, noise=False), artefacts=ArtefactConfig(enabled=False))


def reflectors(points, speed_mps: float) -> Scenario:
    """Nothing but point reflectors (x, y, dB) on a straight road driven at a constant speed."""
    return Scenario(
        name="reflectors",
        drive=DriveConfig(constant_speed_mps=speed_mps),
        world=WorldConfig(procedural=False, extra_points=tuple(points)),
        traffic=NO_TRAFFIC,
    )


def centroid(power: np.ndarray, row: int, col: int, half_rows: int = 4, half_bins: int = 8):
    """(row, bin) power centroid around a peak, in linear power above the empty background."""
    s = CLEAN.sensor
    lin = 10.0 ** ((power.astype(np.float64) * 255.0 * s.db_per_count + s.floor_db) / 10.0)
    lin -= np.median(lin)
    rows = np.arange(row - half_rows, row + half_rows + 1)
    win = lin[np.mod(rows, lin.shape[0])][:, col - half_bins: col + half_bins + 1]
    win = np.clip(win, 0, None)
    rr, bb = np.meshgrid(rows, np.arange(col - half_bins, col + half_bins + 1), indexing="ij")
    return float((win * rr).sum() / win.sum()), float((win * bb).sum() / win.sum())


def test_static_point_target_at_expected_range_and_azimuth():
    x, y = 30.0, 20.0
    sim = Simulator(0, 1, reflectors([(x, y, 60.0)], speed_mps=0.0), CLEAN)
    fr = sim.frame(0)
    power = fr.scan.power
    a, b = np.unravel_index(np.argmax(power), power.shape)
    row_c, bin_c = centroid(power, a, b)
    expect_bin = np.hypot(x, y) / RES - 0.5  # bin b is centred at (b + 0.5)·res
    expect_row = np.arctan2(y, x) / D_AZ  # azimuth 0 = +x, growing towards +y
    assert abs(bin_c - expect_bin) < 0.1
    assert abs(row_c - expect_row) < 0.05
    # and through the shared polar->Cartesian geometry: pixel (cW - x/res, cW + y/res)
    cart = polar_to_cartesian(fr.scan, 0.2, 512)
    r, c = np.unravel_index(np.argmax(cart), cart.shape)
    assert abs(r - (255.5 - x / 0.2)) <= 1.0 and abs(c - (255.5 + y / 0.2)) <= 1.0
    # nothing else in the sweep: away from the target every row is the same noise-floor profile
    far = np.ones_like(power, bool)
    far[max(0, a - 5): a + 6, max(0, b - 15): b + 16] = False
    floor = np.median(power, axis=0, keepdims=True)
    assert np.abs(power - floor)[far].max() <= 1.01 / 255


def test_motion_distortion_displaces_targets_by_speed_times_time_offset():
    v = 10.0
    k = 4  # sweep 4 starts at t = 1.0 s
    targets = [(10.6, 20.0), (12.0, -20.0)]  # abeam right (seen early) and left (seen late)
    sim = Simulator(0, k + 1, reflectors([(x, y, 60.0) for x, y in targets], speed_mps=v), CLEAN)
    first = sim.frame(0).scan.timestamps_us[0]
    fr = sim.frame(k)
    t_rows = (fr.scan.timestamps_us - first) * 1e-6
    t_mid = t_rows.mean()
    power = fr.scan.power
    shifts = []
    for tx, ty in targets:
        # from the maths: the ego is at (v t, 0) heading +x; find the row that sees the target
        a = 0
        for _ in range(5):
            a = int(np.rint(np.mod(np.arctan2(ty, tx - v * t_rows[a]), 2 * np.pi) / D_AZ)) % 400
        rel_row = np.array([tx - v * t_rows[a], ty])  # sensor frame at that azimuth's time
        rel_mid = np.array([tx - v * t_mid, ty])  # where an undistorted (mid-time) sweep puts it
        b = int(np.rint(np.hypot(*rel_row) / RES - 0.5))
        sub = power[max(0, a - 3): a + 4, b - 6: b + 7]
        da, db = np.unravel_index(np.argmax(sub), sub.shape)
        row_c, bin_c = centroid(power, max(0, a - 3) + da, b - 6 + db)
        rng_m, phi = (bin_c + 0.5) * RES, row_c * D_AZ
        measured = rng_m * np.array([np.cos(phi), np.sin(phi)])
        np.testing.assert_allclose(measured, rel_row, atol=0.03)
        shift = measured - rel_mid
        np.testing.assert_allclose(shift, [v * (t_mid - t_rows[a]), 0.0], atol=0.03)
        shifts.append(shift[0])
    # the right target is seen before mid-sweep (pushed forward), the left one after
    assert shifts[0] > 0.5 and shifts[1] < -0.5


def test_drive_written_in_oxford_layout_round_trips_through_the_reader(tmp_path):
    frames = 5
    seq = write_drive(tmp_path / "seq", seed=3, frames=frames, scenario="urban", config=SHORT, progress=False)
    mem = list(simulate_drive(3, frames, "urban", SHORT))
    read = read_sequence(seq)
    assert len(read) == frames
    for k, (f_mem, f_disk) in enumerate(zip(mem, read)):
        s_mem, s_disk = f_mem.scan, f_disk.scan
        assert f_disk.timestamp_us == s_mem.timestamp_us
        assert (tmp_path / "seq" / "radar" / f"{s_mem.timestamp_us}.png").is_file()
        np.testing.assert_array_equal(s_disk.timestamps_us, s_mem.timestamps_us)
        np.testing.assert_array_equal(s_disk.power, s_mem.power)
        np.testing.assert_array_equal(s_disk.valid, s_mem.valid)
        np.testing.assert_allclose(s_disk.azimuths_rad, s_mem.azimuths_rad, atol=1e-6)
        label = cv2.imread(str(seq / "labels" / f"{s_mem.timestamp_us}.png"), cv2.IMREAD_UNCHANGED)
        assert label.dtype == np.uint8 and label.ndim == 2
        np.testing.assert_array_equal(label, f_mem.static_label)
        if k:
            np.testing.assert_array_equal(f_disk.gt_pose_rel, f_mem.pose_rel)
    stamps = (seq / "radar.timestamps").read_text().split()
    assert stamps[0::2] == [str(f.scan.timestamp_us) for f in mem] and set(stamps[1::2]) == {"1"}


def test_chaining_ground_truth_rows_reproduces_the_trajectory(tmp_path):
    frames = 24  # 6 s: long enough to leave the lead-in straight on some seeds
    seq = write_drive(tmp_path / "seq", seed=11, frames=frames, scenario="heavy_traffic",
                      config=SimConfig().with_sensor(num_bins=300), progress=False)
    sim = Simulator(11, frames, "heavy_traffic", SimConfig().with_sensor(num_bins=300))
    truth = np.stack([sim.pose_mid(k) for k in range(frames)])
    rel = np.stack([f.gt_pose_rel for f in list(read_sequence(seq))[1:]])
    chained = chain_relative(rel, start=truth[0])
    np.testing.assert_allclose(chained, truth, atol=1e-9)
    # gt mid times are the means of the azimuth timestamps; radar timestamps are the PNG names
    lines = (seq / "gt" / "radar_odometry.csv").read_text().splitlines()
    head = lines[0].split(",")
    row = dict(zip(head, lines[1].split(",")))
    ts1 = sim.timestamps_us(1)
    assert int(row["source_radar_timestamp"]) == ts1[0]
    assert abs(int(row["source_timestamp"]) - ts1[0] - (ts1 - ts1[0]).mean()) <= 0.5


def _first_hits(orig, dirs, a, b):
    """Nearest intersection range of each ray with segments a->b ([S, 2] or [A, S, 2]); inf if none."""
    a = np.broadcast_to(a, (len(orig),) + a.shape[-2:])
    b = np.broadcast_to(b, (len(orig),) + b.shape[-2:])
    e = b - a
    w = a - orig[:, None]
    cross = lambda p, q: p[..., 0] * q[..., 1] - p[..., 1] * q[..., 0]  # noqa: E731
    den = cross(dirs[:, None], e)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = cross(w, e) / den
        u = cross(w, dirs[:, None]) / den
    t = np.where((u >= 0) & (u <= 1) & (t > 0.5), t, np.inf)
    return t.min(axis=1) if t.shape[1] else np.full(len(orig), np.inf)


def test_row_culling_finds_the_same_hits_as_casting_every_ray_at_every_segment():
    sim = Simulator(1, 80, "urban", SimConfig().with_sensor(num_bins=100))
    total = 0
    for k in (0, 40, 79):
        t = sim.drive_time_s(sim.timestamps_us(k))
        orig, yaw = sim.drive.pose_at(t)
        phi = yaw + np.arange(400) * D_AZ
        dirs = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        near, _ = sim.world.near(orig[200], 170.0)
        a, b = sim.world.seg_a_m[near], sim.world.seg_b_m[near]
        dense = ray_segment_hits(orig, dirs, a, b, 0.5, 162.8)
        rows, segs = candidate_rows(orig, yaw, 0.0, D_AZ, a, b)
        culled = ray_pair_hits(orig, dirs, a, b, rows, segs, 0.5, 162.8)
        assert len(rows) < 0.2 * 400 * len(a)  # the point of culling
        assert set(zip(*map(np.ndarray.tolist, dense[:2]))) == set(zip(*map(np.ndarray.tolist, culled[:2])))
        total += len(dense[0])
    assert total > 1000


def test_moving_vehicles_are_never_labelled_static():
    sim = Simulator(4, 13, "heavy_traffic", SHORT)
    checked = 0
    for k in (0, 6, 12):
        _, label, _, ts = sim.render(k)
        t = sim.drive_time_s(ts)
        orig, yaw = sim.drive.pose_at(t)
        phi = yaw + np.arange(400) * D_AZ
        dirs = np.stack([np.cos(phi), np.sin(phi)], axis=1)
        centre, head, active = sim.traffic.box_poses(sim.drive, t)
        corners = box_corners_batch(centre, head, sim.traffic.length_m, sim.traffic.width_m)
        corners[~active] = 1e9
        veh = _first_hits(orig, dirs, corners.reshape(400, -1, 2), np.roll(corners, -1, axis=2).reshape(400, -1, 2))
        stat = _first_hits(orig, dirs, sim.world.seg_a_m, sim.world.seg_b_m)
        rows = np.flatnonzero((veh < stat) & (veh < 45.0))
        for a in rows:
            b = int(np.rint(veh[a] / RES - 0.5))
            assert not label[a, b - 2: b + 3].any(), f"sweep {k} row {a}: a moving vehicle labelled static"
        checked += len(rows)
        assert label.any()  # the static world is labelled
    assert checked > 50  # the test saw vehicles


def test_without_a_static_world_nothing_is_labelled_static():
    # vehicles alone, with ghosts, streaks, phase-noise arcs and near-range clutter switched on
    sc = SCENARIOS["heavy_traffic"].with_world(procedural=False)
    sim = Simulator(2, 3, sc, SHORT)
    for fr in sim:
        assert not fr.static_label.any()
        assert fr.scan.power.max() > 0.4  # there were strong (moving) returns (real Navtech peaks ≈ 0.5)


def test_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path):
    cfg = SimConfig().with_sensor(num_bins=400)
    dirs = [write_drive(tmp_path / n, seed=s, frames=3, config=cfg, progress=False)
            for n, s in (("a", 5), ("b", 5), ("c", 6))]

    def files(d: Path):
        return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}

    fa, fb, fc = (files(d) for d in dirs)
    assert fa == fb and len(fa) == 3 * 2 + 2
    assert fa.keys() != fc.keys()  # another seed starts at another time...
    radar_a = [v for k, v in fa.items() if k.startswith("radar/")]
    radar_c = [v for k, v in fc.items() if k.startswith("radar/")]
    assert all(x[11:] != y[11:] for x, y in zip(radar_a, radar_c))  # ...in another world


def test_scenarios_differ():
    sims = {n: Simulator(5, 60, n, SimConfig().with_sensor(num_bins=300)) for n in SCENARIOS}
    speed = {n: float(np.mean(s.drive.speed_at(np.arange(0, 15, 0.25)))) for n, s in sims.items()}
    segs_per_km = {n: s.world.num_segments / s.drive.road.length_m * 1e3 for n, s in sims.items()}
    assert speed["highway"] > speed["urban"] > speed["heavy_traffic"]
    assert sims["heavy_traffic"].traffic.num_boxes > 1.5 * sims["urban"].traffic.num_boxes
    assert segs_per_km["open"] < 0.5 * segs_per_km["urban"]
    assert sims["highway"].drive.road.lanes_per_direction == 3
    powers = {n: s.frame(20).scan.power for n, s in sims.items()}
    names = list(powers)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            assert not np.array_equal(powers[names[i]], powers[names[j]])


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_ego_drive_respects_speed_and_yaw_rate_limits(name):
    cfg = SCENARIOS[name].drive
    for seed in range(3):
        sim = Simulator(seed, 240, name, SimConfig().with_sensor(num_bins=100))
        t = np.arange(0.0, 60.0, 0.05)
        xy, yaw = sim.drive.pose_at(t)
        speed = np.hypot(*np.diff(xy, axis=0).T) / 0.05
        yaw_rate = np.degrees(np.abs(np.diff(np.unwrap(yaw)))) / 0.05
        assert speed.max() <= cfg.max_speed_mps * 1.01 and speed.min() >= 0.0
        assert yaw_rate.max() <= cfg.max_yaw_rate_dps * 1.02
        assert np.all(np.isfinite(xy))
    np.testing.assert_allclose(sim.drive.pose_at(0.0)[0], [0.0, 0.0], atol=1e-9)


def test_urban_drives_turn_stop_and_accelerate():
    stops = turns = 0
    for seed in range(4):
        sim = Simulator(seed, 400, "urban", SimConfig().with_sensor(num_bins=100))
        stops += len(sim.drive.stops)
        turns += len(sim.drive.road.turn_spans_m)
    assert stops > 0 and turns > 0


def test_bad_arguments_raise_typed_errors(tmp_path):
    cfg = SimConfig().with_sensor(num_bins=100)
    write_drive(tmp_path, seed=1, frames=2, config=cfg, progress=False)
    write_drive(tmp_path, seed=1, frames=2, config=cfg, progress=False)  # the same drive again: fine
    with pytest.raises(SimConfigError, match="another drive"):
        write_drive(tmp_path, seed=2, frames=2, config=cfg, progress=False)
    with pytest.raises(SimConfigError, match="urban"):
        simulate_drive(0, 3, scenario="mars")
    with pytest.raises(SimConfigError, match="seed"):
        simulate_drive(-1, 3)
    with pytest.raises(SimConfigError, match="frames"):
        simulate_drive(0, 0)


def test_full_resolution_sweep_and_cli(tmp_path):
    out = tmp_path / "drive"
    subprocess.run([sys.executable, "-m", "radar_odom", "simulate", str(out), "--frames", "2", "--seed", "1",
                    "--scenario", "urban", "--no-progress"], check=True, capture_output=True)
    pngs = sorted((out / "radar").glob("*.png"))
    assert len(pngs) == 2 and len(list((out / "labels").glob("*.png"))) == 2
    img = cv2.imread(str(pngs[0]), cv2.IMREAD_UNCHANGED)
    assert img.shape == (400, 11 + 3768) and img.dtype == np.uint8
    seq = read_sequence(out)
    fr = seq[1]
    s = fr.scan
    assert s.power.shape == (400, 3768) and s.power.dtype == np.float32
    np.testing.assert_array_equal(np.diff(s.timestamps_us), 625)  # 4 Hz, 400 azimuths
    np.testing.assert_array_equal(np.diff(s.encoder_counts.astype(int)), 14)
    assert int(pngs[1].stem) - int(pngs[0].stem) == 250_000
    assert fr.gt_pose_rel is not None and 0.0 < fr.gt_pose_rel[0] < 15.0 * 0.25
    np.testing.assert_array_equal(np.round(s.power * 255) / 255, s.power)
    label = cv2.imread(str(out / "labels" / pngs[1].name), cv2.IMREAD_UNCHANGED)
    assert set(np.unique(label)) <= {0, 255} and label.any()
