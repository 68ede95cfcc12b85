import numpy as np
import pytest

from radar_odom import se2 as S

hyp = pytest.importorskip("hypothesis")
from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

finite = st.floats(-100, 100, allow_nan=False)
angle = st.floats(-np.pi, np.pi, allow_nan=False)


@given(finite, finite, angle)
def test_inverse_composes_to_identity(x, y, yaw):
    t = S.se2(x, y, yaw)
    np.testing.assert_allclose(S.invert(t) @ t, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(t @ S.invert(t), np.eye(3), atol=1e-9)


@given(finite, finite, angle)
def test_xyyaw_round_trip(x, y, yaw):
    back = S.to_xyyaw(S.se2(x, y, yaw))
    np.testing.assert_allclose(back[:2], [x, y], atol=1e-9)
    assert abs(S.wrap_angle(back[2] - yaw)) < 1e-9


def test_oxford_convention_point_mapping():
    # later frame 2 m ahead and turned +90° (x towards y): a point 1 m ahead of the later
    # frame is 2 m ahead and 1 m to the right in the earlier frame.
    t = S.se2(2.0, 0.0, np.pi / 2)
    p = t @ np.array([1.0, 0.0, 1.0])
    np.testing.assert_allclose(p[:2], [2.0, 1.0], atol=1e-12)


def test_chain_and_relative_are_inverse():
    rng = np.random.default_rng(0)
    rel = np.column_stack([rng.uniform(0, 3, 50), rng.normal(0, 0.2, 50), rng.normal(0, 0.05, 50)])
    absolute = S.chain_relative(rel)
    assert absolute.shape == (51, 3, 3)
    np.testing.assert_allclose(S.relative_from_absolute(absolute), rel, atol=1e-9)


def test_wrap_angle_range():
    a = S.wrap_angle(np.array([np.pi, -np.pi, 3 * np.pi, 0.1, -7.0]))
    assert np.all(a <= np.pi) and np.all(a > -np.pi)
    np.testing.assert_allclose(np.cos(a), np.cos([np.pi, -np.pi, 3 * np.pi, 0.1, -7.0]), atol=1e-12)


@given(finite, finite, angle)
def test_se2_exp_inverts_se2_log(x, y, yaw):
    back = S.se2_exp(S.se2_log([x, y, yaw]))
    np.testing.assert_allclose(S.se2(*back), S.se2(x, y, yaw), atol=1e-9)


@given(st.floats(-5, 5, allow_nan=False), st.floats(-1, 1, allow_nan=False), st.floats(-0.3, 0.3, allow_nan=False),
       st.integers(1, 9))
def test_se2_exp_of_k_times_log_repeats_the_pose(x, y, yaw, k):
    # a constant twist held k periods: the one-period pose composed k times (a circular arc)
    out = S.se2_exp(k * S.se2_log([x, y, yaw]))
    np.testing.assert_allclose(S.se2(*out), np.linalg.matrix_power(S.se2(x, y, yaw), k), atol=1e-9)


def test_se2_exp_is_an_arc_and_a_line_without_a_turn():
    # a quarter circle of radius 10 m turning right (+yaw): ends 10 m ahead, 10 m to the right
    np.testing.assert_allclose(S.se2_exp([10 * np.pi / 2, 0.0, np.pi / 2]), [10.0, 10.0, np.pi / 2], atol=1e-12)
    np.testing.assert_allclose(S.se2_exp([3.0, -1.0, 0.0]), [3.0, -1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(S.se2_log([3.0, -1.0, 1e-7]), [3.0, -1.0, 1e-7], atol=1e-6)
