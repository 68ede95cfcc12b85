"""TUM and KITTI trajectory files: hand-computed lines and lossless round trips."""
import math

import numpy as np
import pytest

from radar_odom.evaluation.trajectory import read_kitti, read_tum, write_kitti, write_tum
from radar_odom.se2 import chain_relative, se2

T0 = 1547131046353776


def drive(n=50, seed=0):
    rng = np.random.default_rng(seed)
    rel = np.column_stack([rng.uniform(0, 3, n - 1), rng.normal(0, 0.1, n - 1), rng.normal(0, 0.2, n - 1)])
    return chain_relative(rel)  # yaw wraps past ±π along the way


def test_tum_line_for_a_known_pose(tmp_path):
    path = write_tum(tmp_path / "t.txt", [T0], [se2(1.0, 2.0, math.pi / 2)])
    parts = path.read_text().split()
    assert parts[0] == "1547131046.353776"  # exact seconds from integer µs
    np.testing.assert_allclose(
        [float(p) for p in parts[1:]], [1.0, 2.0, 0.0, 0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-15
    )


def test_kitti_line_for_a_known_pose(tmp_path):
    path = write_kitti(tmp_path / "k.txt", [se2(1.0, 2.0, math.pi / 2)])
    m = np.array([float(p) for p in path.read_text().split()]).reshape(3, 4)
    np.testing.assert_allclose(m, [[0, -1, 0, 1], [1, 0, 0, 2], [0, 0, 1, 0]], atol=1e-15)


def test_tum_round_trip(tmp_path):
    poses = drive()
    ts = T0 + np.arange(len(poses)) * 250_000 + 7
    back_ts, back = read_tum(write_tum(tmp_path / "sub" / "t.txt", ts, poses))
    np.testing.assert_array_equal(back_ts, ts)
    np.testing.assert_allclose(back, poses, atol=1e-12)


def test_kitti_round_trip(tmp_path):
    poses = drive(seed=1)
    np.testing.assert_allclose(read_kitti(write_kitti(tmp_path / "k.txt", poses)), poses, atol=1e-12)


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match=r"shape \(3, 4\)"):
        write_kitti(tmp_path / "k.txt", np.zeros((3, 4)))
    with pytest.raises(ValueError, match="2 timestamps for 1 poses"):
        write_tum(tmp_path / "t.txt", [T0, T0 + 1], [np.eye(3)])
    (tmp_path / "bad.txt").write_text("# comment\n1 2 3\n")
    with pytest.raises(ValueError, match="line 2: 3 numbers, expected 8"):
        read_tum(tmp_path / "bad.txt")
