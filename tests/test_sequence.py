"""Recording folders: time order, laziness, and ground truth in the Oxford relative convention."""
import math

import cv2
import numpy as np
import pytest

from radar_odom import RadarScan, ScanFormatError, SequenceError, read_sequence, write_scan
from radar_odom.io import oxford_gt_rows, write_oxford_ground_truth, write_radar_timestamps
from radar_odom.se2 import chain_relative

T0 = 1547131046353776


def sweep(t0_us, a=8, b=32, seed=0):
    rng = np.random.default_rng(seed)
    return RadarScan.from_arrays(
        t0_us + np.arange(a) * 625, np.arange(a) * 14 * 2 * math.pi / 5600, rng.integers(0, 256, (a, b), dtype=np.uint8)
    )


def oxford_seq(tmp_path, n=5):
    names = T0 + np.arange(n) * 250_000
    for k in [k for k in (3, 0, 4, 1, 2) if k < n]:  # written out of order
        write_scan(tmp_path / "radar", sweep(int(names[k]), seed=k))
    return names


# ---------------------------------------------------------------- Oxford


def test_oxford_sweeps_in_time_order_with_matched_ground_truth(tmp_path):
    names = oxford_seq(tmp_path)
    rel = np.array([[2.4, 0.01, 0.002], [2.5, -0.02, -0.01], [2.6, 0.0, 0.03], [2.3, 0.1, 0.0]])
    rows = oxford_gt_rows(names, names + 2500, rel)
    assert rows[0][:4] == (names[1], names[0], names[1] + 2500, names[0] + 2500)  # source = later
    rows = rows[::-1] + [(1, 2, 3, 4, 9.0, 9.0, 9.0)]  # any row order; unrelated rows ignored
    write_oxford_ground_truth(tmp_path, rows)
    from radar_odom.errors import GroundTruthWarning

    with pytest.warns(GroundTruthWarning, match="implausible pose .* on line 6"):  # the unrelated row's yaw of 9 rad
        seq = read_sequence(tmp_path)
    assert seq.format == "oxford" and len(seq) == 5
    np.testing.assert_array_equal(seq.timestamps_us, names)
    assert [p.name for p in seq.paths] == [f"{t}.png" for t in names]
    np.testing.assert_array_equal(seq.gt_relative, rel)  # repr-written floats read back exactly
    frames = list(seq)
    assert [f.index for f in frames] == [0, 1, 2, 3, 4]
    assert [f.scan.timestamp_us for f in frames] == list(names)
    assert frames[0].gt_pose_rel is None
    np.testing.assert_array_equal(frames[2].gt_pose_rel, rel[1])
    np.testing.assert_allclose(seq.gt_absolute(), chain_relative(rel))
    assert seq[-1].timestamp_us == names[-1]


def test_oxford_gt_csv_columns_as_documented(tmp_path):
    path = write_oxford_ground_truth(tmp_path, oxford_gt_rows([10, 20], [15, 25], [[1.5, -0.5, 0.25]]))
    header, row = path.read_text().splitlines()
    assert header == (
        "source_timestamp,destination_timestamp,x,y,z,roll,pitch,yaw,"
        "source_radar_timestamp,destination_radar_timestamp"
    )
    assert row == "25,15,1.5,-0.5,0.0,0.0,0.0,0.25,20,10"


def test_radar_timestamps_file(tmp_path):
    path = write_radar_timestamps(tmp_path, [T0, T0 + 250_000], valid=[True, False])
    assert path.read_text() == f"{T0} 1\n{T0 + 250_000} 0\n"


def test_missing_and_partial_ground_truth(tmp_path):
    names = oxford_seq(tmp_path, n=3)
    assert read_sequence(tmp_path).gt_relative is None
    assert read_sequence(tmp_path).gt_absolute() is None
    write_oxford_ground_truth(tmp_path, oxford_gt_rows(names[1:], names[1:], [[2.0, 0.0, 0.0]]))
    seq = read_sequence(tmp_path)
    assert np.isnan(seq.gt_relative[0]).all() and np.array_equal(seq.gt_relative[1], [2.0, 0.0, 0.0])
    assert seq[1].gt_pose_rel is None
    np.testing.assert_array_equal(seq[2].gt_pose_rel, [2.0, 0.0, 0.0])


def test_sweeps_are_decoded_only_when_asked_for(tmp_path):
    names = oxford_seq(tmp_path, n=3)
    (tmp_path / "radar" / f"{names[1]}.png").write_bytes(b"not a png at all")
    seq = read_sequence(tmp_path)  # opening does not decode
    assert seq[0].scan.timestamp_us == names[0]
    with pytest.raises(ScanFormatError, match=f"{names[1]}.png: not a PNG"):
        seq[1]


def test_bad_ground_truth_csv(tmp_path):
    oxford_seq(tmp_path, n=2)
    gt = tmp_path / "gt" / "radar_odometry.csv"
    gt.parent.mkdir()
    gt.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(SequenceError, match="header lacks source_radar_timestamp") as e:
        read_sequence(tmp_path)
    assert str(gt) in str(e.value)
    gt.write_text("source_radar_timestamp,destination_radar_timestamp,x,y,yaw\n1,2,3.0,oops,0\n")
    with pytest.raises(SequenceError, match="line 2"):
        read_sequence(tmp_path)


def test_folders_without_sweeps(tmp_path):
    with pytest.raises(SequenceError, match="no radar sweeps found"):
        read_sequence(tmp_path)
    (tmp_path / "radar").mkdir()
    with pytest.raises(SequenceError, match="holds no radar PNGs"):
        read_sequence(tmp_path)
    cv2.imwrite(str(tmp_path / "radar" / "first.png"), np.zeros((4, 20), np.uint8))
    with pytest.raises(SequenceError, match="integer timestamps, got first.png"):
        read_sequence(tmp_path)
    with pytest.raises(SequenceError, match="nope: does not exist; give a recording folder"):
        read_sequence(tmp_path / "nope")
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(SequenceError, match="a-file: not a folder; give a recording folder"):
        read_sequence(tmp_path / "a-file")


# ---------------------------------------------------------------- z-up datasets
# A hand-made drive: heading north-east, two straight 2 m steps, then a right turn on a 20 m
# circle, 0.1 rad per sweep. In the Oxford frame (y right, z down) a straight step is
# (2, 0, 0) and a right-turn step is (R sin θ, +R(1 − cos θ), +θ).
R_M, TH = 20.0, 0.1
EXPECTED_REL = np.array(
    [[2.0, 0.0, 0.0]] * 2 + [[R_M * math.sin(TH), R_M * (1 - math.cos(TH)), TH]] * 3
)


def zup_drive(start_xy, heading):
    """Absolute z-up poses (x, y, yaw CCW) of the drive above."""
    poses = [(start_xy[0], start_xy[1], heading)]
    for dx, dy_right, dyaw_cw in EXPECTED_REL:
        x, y, h = poses[-1]
        dy_left = -dy_right  # z-up body frame: y points left
        c, s = math.cos(h), math.sin(h)
        poses.append((x + c * dx - s * dy_left, y + s * dx + c * dy_left, h - dyaw_cw))
    return np.array(poses)


def test_boreas_enu_poses_become_oxford_relatives(tmp_path):
    poses = zup_drive((628_000.0, 4_848_000.0), math.pi / 4)  # UTM-sized ENU coordinates
    names = 1606417230036848 + np.arange(6) * 250_000  # mid-sweep times
    for k, t in enumerate(names):
        write_scan(tmp_path / "radar" / f"{t}.png", sweep(int(t) - 2187, seed=k))
    lines = [
        "GPSTime,easting,northing,altitude,vel_east,vel_north,vel_up,roll,pitch,heading,angvel_z,angvel_y,angvel_x"
    ]
    for t, (e, n, h) in zip(names, poses):
        lines.append(
            f"{t},{float(e)!r},{float(n)!r},{85.0 + 0.1 * (t - names[0]) / 250_000},"
            f"10.0,10.0,0.0,0.0,0.0,{float(h)!r},0.0,0.0,0.0"
        )
    (tmp_path / "applanix").mkdir()
    (tmp_path / "applanix" / "radar_poses.csv").write_text("\n".join(lines) + "\n")
    seq = read_sequence(tmp_path)
    assert seq.format == "boreas"
    assert seq[0].scan.range_offset_m == -0.31
    np.testing.assert_allclose(seq.gt_relative, EXPECTED_REL, atol=1e-9)
    # chained Oxford poses are the ENU drive seen from the first pose, mirrored (y, yaw negated)
    h0 = poses[0, 2]
    d = poses[:, :2] - poses[0, :2]
    fwd = d @ [math.cos(h0), math.sin(h0)]
    left = d @ [-math.sin(h0), math.cos(h0)]
    ab = seq.gt_absolute()
    np.testing.assert_allclose(ab[:, 0, 2], fwd, atol=1e-8)
    np.testing.assert_allclose(ab[:, 1, 2], -left, atol=1e-8)
    np.testing.assert_allclose(np.arctan2(ab[:, 1, 0], ab[:, 0, 0]), -(poses[:, 2] - h0), atol=1e-12)


def write_mulran_poses(path, stamps_ns, poses_xyyaw):
    lines = []
    for t, (x, y, h) in zip(stamps_ns, poses_xyyaw):
        c, s = math.cos(h), math.sin(h)
        m = [c, -s, 0.0, x, s, c, 0.0, y, 0.0, 0.0, 1.0, 3.5]
        lines.append(",".join([str(int(t))] + [repr(float(v)) for v in m]))
    path.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("sub", ["polar", "sensor_data/radar/polar"])
def test_mulran_poses_matched_at_mid_sweep_become_oxford_relatives(tmp_path, sub):
    poses = zup_drive((353.0, -120.0), 3 * math.pi / 4)  # heading north-west
    ends_ns = 1566535954883011000 + np.arange(6, dtype=np.int64) * 250_000_000
    folder = tmp_path / sub
    folder.mkdir(parents=True)
    for k, t in enumerate(ends_ns):
        cv2.imwrite(str(folder / f"{t}.png"), np.full((32, 16), k, np.uint8))
    mid_ns = ends_ns - 125_000_000 + 2_000_000  # pose stamps a little off the mid times
    decoys = zup_drive((0.0, 0.0), 0.0)  # wrong poses at the END times: must not be picked
    write_mulran_poses(tmp_path / "global_pose.csv", np.concatenate([ends_ns, mid_ns]), np.concatenate([decoys, poses]))
    seq = read_sequence(tmp_path)
    assert seq.format == "mulran"
    np.testing.assert_array_equal(seq.timestamps_us, ends_ns // 1000)
    np.testing.assert_allclose(seq.gt_relative, EXPECTED_REL, atol=1e-9)
    assert seq[3].scan.power[0, 0] == pytest.approx(3 / 255)


def test_mulran_pose_too_far_away_leaves_a_gap(tmp_path):
    ends_ns = 1566535954883011000 + np.arange(3, dtype=np.int64) * 250_000_000
    (tmp_path / "polar").mkdir()
    for t in ends_ns:
        cv2.imwrite(str(tmp_path / "polar" / f"{t}.png"), np.zeros((32, 16), np.uint8))
    stamps = ends_ns - 125_000_000
    stamps[2] += 200_000_000  # 0.2 s off (> 0.1 s default): no ground truth for the last sweep
    write_mulran_poses(tmp_path / "global_pose.csv", stamps, zup_drive((0.0, 0.0), 0.0)[:3])
    seq = read_sequence(tmp_path)
    np.testing.assert_allclose(seq.gt_relative[0], [2.0, 0.0, 0.0], atol=1e-12)
    assert np.isnan(seq.gt_relative[1]).all()
    assert read_sequence(tmp_path, max_pose_gap_s=0.3).gt_relative[1, 0] == pytest.approx(2.0)


def test_bad_pose_files(tmp_path):
    (tmp_path / "polar").mkdir()
    cv2.imwrite(str(tmp_path / "polar" / "1566535954883011000.png"), np.zeros((32, 16), np.uint8))
    cv2.imwrite(str(tmp_path / "polar" / "1566535955133011000.png"), np.zeros((32, 16), np.uint8))
    (tmp_path / "global_pose.csv").write_text("1566535954758011000,1,0,0\n")
    with pytest.raises(SequenceError, match="line 1: 4 columns, expected 13"):
        read_sequence(tmp_path)
    b = tmp_path / "b"
    write_scan(b / "radar", sweep(T0))
    (b / "applanix").mkdir()
    (b / "applanix" / "radar_poses.csv").write_text("GPSTime,easting,northing\n1,2,3\n")
    with pytest.raises(SequenceError, match="header lacks altitude, roll, pitch, heading"):
        read_sequence(b)
