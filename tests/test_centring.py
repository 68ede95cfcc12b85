"""Yaw centring (`radar_odom.odometry.centring`): the frames' maths against SE(2) matrices, and the
odometer drawing each sweep turned by the predicted yaw."""
import math

import numpy as np
import pytest

from radar_odom.odometry.centring import MAX_TURN_RAD, next_turn, uncentre
from radar_odom.se2 import invert, se2, to_xyyaw


def test_uncentre_inverts_drawing_both_sweeps_turned():
    """Q = R(−a_ref)·T·R(a_new) is what the graph sees; uncentre gives T back, for any turns."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        t = np.array([rng.uniform(-8, 8), rng.uniform(-3, 3), rng.uniform(-0.3, 0.3)])
        a_ref, a_new = rng.uniform(-0.4, 0.4, size=2)
        q = to_xyyaw(se2(0, 0, -a_ref) @ se2(*t) @ se2(0, 0, a_new))
        pose, _ = uncentre(q, np.eye(3), a_ref, a_new)
        np.testing.assert_allclose(pose, t, atol=1e-12)


def test_uncentre_turns_the_covariance_with_the_translation_only():
    cov = np.diag([4.0, 0.25, 1e-4])
    a = math.radians(90)
    _, out = uncentre(np.zeros(3), cov, a, 0.3)
    # the residual's x axis is the reference's y axis after a quarter turn; yaw is unchanged
    np.testing.assert_allclose(out, np.diag([0.25, 4.0, 1e-4]), atol=1e-12)
    pose, same = uncentre([1.0, 2.0, 0.01], cov, 0.0, 0.0)
    np.testing.assert_allclose(pose, [1.0, 2.0, 0.01])
    np.testing.assert_allclose(same, cov)


def test_next_turn_cancels_the_predicted_yaw():
    assert next_turn(0.0, 0.01) == pytest.approx(-0.01)
    assert next_turn(-0.05, -0.02) == pytest.approx(-0.03)
    assert next_turn(0.07, None) == 0.07  # no prediction yet: the reference's turn kept
    assert next_turn(0.07, float("nan")) == 0.07
    assert next_turn(math.pi - 0.01, -0.03) == pytest.approx(-math.pi + 0.02)  # wrapped
    # drawn so, the graph's residual yaw is 0 when the prediction holds
    yaw = 0.012
    a_ref = 0.2
    a_new = next_turn(a_ref, yaw)
    q = to_xyyaw(se2(0, 0, -a_ref) @ se2(2.5, 0.1, yaw) @ se2(0, 0, a_new))
    assert q[2] == pytest.approx(0.0, abs=1e-12)


def test_the_turn_limit_is_a_few_degrees():
    assert math.radians(2) < MAX_TURN_RAD <= math.radians(30)


def test_gap_crossing_with_a_turned_reference_composes_back():
    """The gap path draws the new sweep at (R(−a_ref)·P)⁻¹ against a reference drawn turned by
    a_ref: a residual of 0 must give back the prediction P."""
    from radar_odom.odometry.gaps import compose_residual

    p = np.array([9.0, 0.4, 0.05])
    a_ref = 0.12
    turned = to_xyyaw(se2(0, 0, -a_ref) @ se2(*p))
    drawn_frame = invert(se2(*turned))
    # what the graph sees for the truth T = P: the drawn frames' relative pose
    q = to_xyyaw(se2(0, 0, -a_ref) @ se2(*p) @ drawn_frame)
    np.testing.assert_allclose(q, 0.0, atol=1e-12)
    pose, _ = uncentre(*compose_residual(q, np.eye(3), turned), a_ref, 0.0)
    np.testing.assert_allclose(pose, p, atol=1e-12)


# ------------------------------------------------------------------ the odometer
def _counting(odo):
    calls = []
    run = odo._model.run

    def counted(feeds):
        calls.append(1)
        return run(feeds)

    odo._model.run = counted
    return calls


@pytest.mark.parametrize("steps, yaw", [(4, 0.05), (8, -0.05)])
def test_centred_odometer_recovers_known_motion(tiny_model, steps, yaw):
    """A steady turn on the tiny raw model: the centred odometer reads it as the plain one does, with
    one graph call per sweep until the drawn frame has turned past `MAX_TURN_RAD` (then one more)."""
    from test_odometer import drive

    from radar_odom import RadarOdometer

    rel = (1.6, 0.0, yaw)
    scans = drive(rel, steps, seed=1)
    odo = RadarOdometer(tiny_model, motion_prior=False, centre_yaw=True)
    calls = _counting(odo)
    ests = [odo.step(s) for s in scans][1:]
    for est in ests:
        assert not est.flags
        assert abs(est.pose[0] - rel[0]) < 0.8 and abs(est.pose[1] - rel[1]) < 0.8
        assert abs(est.pose[2] - rel[2]) < 0.025
    # turns drawn: none for the first match (no velocity yet), then −yaw more per sweep, back to 0
    # (a second call) past the limit
    re_anchors, a = 0, 0.0
    for k in range(steps - 1):
        a = a - (yaw if k else 0.0)
        if abs(a) > MAX_TURN_RAD:
            re_anchors, a = re_anchors + 1, 0.0
    assert len(calls) == steps + re_anchors
    assert (re_anchors > 0) == (steps > 4)
    plain = RadarOdometer(tiny_model, motion_prior=False)
    for s in scans:
        plain.step(s)
    np.testing.assert_allclose(odo.trajectory.poses[-1][:2, 2], plain.trajectory.poses[-1][:2, 2], atol=1.6)


def test_centre_yaw_must_be_a_bool(tiny_model):
    from radar_odom import RadarOdometer
    from radar_odom.errors import ConfigError

    with pytest.raises(ConfigError, match="centre_yaw"):
        RadarOdometer(tiny_model, centre_yaw="yes")
    assert RadarOdometer(tiny_model).centre_yaw is False  # off by default (measured: docs/yaw-precision.md)


@pytest.mark.slow
def test_centring_reads_more_of_a_simulated_bend():
    """The shipped cart-0.4 on a steady simulated bend of 0.5 °/sweep, graph alone: drawn turned by
    the predicted yaw, the bend is read more fully than in the sensor's own frame (measured 28
    sweeps: 0.63 → 0.73 of the turn)."""
    from dataclasses import replace

    from radar_odom import RadarOdometer
    from radar_odom.evaluation.metrics import step_biases
    from radar_odom.model_zoo import pretrained
    from radar_odom.sim.scenarios import get_scenario
    from radar_odom.sim.simulator import simulate_drive

    base = get_scenario("urban")
    drive_ = replace(base.drive, constant_speed_mps=10.0, constant_curvature_per_m=math.radians(0.5) / 2.5)
    frames = list(simulate_drive(5200, 16, replace(base, drive=drive_)))
    gt = np.array([f.pose_rel for f in frames[1:]])[4:]
    slopes = {}
    for centre in (False, True):
        odo = RadarOdometer(pretrained("cart-0.4"), motion_prior=False, centre_yaw=centre)
        est = np.array([e.pose for e in (odo.step(f.scan) for f in frames) if e is not None])[4:]
        slopes[centre] = step_biases(gt, est, turning_deg=0.05)["yaw_slope"]
    assert slopes[True] > slopes[False] + 0.04, slopes


def test_run_centre_yaw_flag_reaches_the_odometer(cli_model, tmp_path, capsys, monkeypatch):
    """`radar-odom run --centre-yaw` runs the odometer with it; without the flag the default (off) holds."""
    from radar_odom import RadarOdometer
    from radar_odom.commands.cli import main
    from radar_odom.runs import run_sequence as rs
    from radar_odom.sim import write_drive

    drive_dir = write_drive(tmp_path / "drive", seed=11, frames=4, progress=False)
    made = []

    class Recording(RadarOdometer):
        def __init__(self, *a, **kw):
            super().__init__(*a, **kw)
            made.append(self.centre_yaw)

    monkeypatch.setattr(rs, "RadarOdometer", Recording)
    for flag, want in (([], False), (["--centre-yaw"], True), (["--no-centre-yaw"], False)):
        out = tmp_path / f"out{len(made)}"
        assert main(["run", str(drive_dir), "--model", str(cli_model), "-o", str(out), "--no-plot", *flag]) == 0
        assert made[-1] is want, flag
    capsys.readouterr()  # the runs' own output
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "--centre-yaw, --no-centre-yaw" in " ".join(capsys.readouterr().out.split())
