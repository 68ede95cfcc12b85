"""The de-skew stage on its own (`radar_odom.odometry.deskew_stage.DeskewStage`), the graph calls faked:
which twist a match's sweeps are drawn with, when the reference is redrawn, what a stream's first match does.
No model: the stage's decisions need only the grid profile and the sweep's azimuth times."""
import math

import numpy as np
import pytest

from radar_odom.odometry.deskew_stage import DESKEW_STEPS, DeskewStage
from radar_odom.odometry.match_stage import Match
from radar_odom.odometry.stream_state import Reference
from radar_odom.profiles import get_profile
from radar_odom.scan import RadarScan

PROFILE = get_profile("cart-0.4")


def sweep(t0_us=0, period_s=0.25, rows=400):
    times = t0_us + np.round(np.arange(rows) * period_s * 1e6 / rows).astype(np.int64)
    return RadarScan.from_arrays(times, np.arange(rows) * 2 * math.pi / rows, np.zeros((rows, 64), np.float32))


def stage(enabled=True, redraw_ok=True, mount_yaw_rad=0.0):
    calls = []

    class Drawer:  # stands in for MatchStage.draw_reference: the reference state, or None (not finite)
        def draw_reference(self, scan, twist, turn):
            calls.append((scan, twist))
            return np.ones(1) if redraw_ok else None

    return DeskewStage(enabled, PROFILE, mount_yaw_rad, Drawer()), calls


def reference(scan, twist):
    """A stream's `Reference`: ``scan`` drawn with ``twist``."""
    return Reference(np.zeros(1), 0, scan, 0.0, twist)


def test_stream_twist_is_the_mean_of_the_last_steps_in_the_radars_frame():
    s, _ = stage(mount_yaw_rad=math.pi / 2)
    assert s.stream_twist(sweep()) is None  # no motion yet
    s.observe((50.0, 0.0, 0.0), 0.25)  # an old outlier, pushed out by the next DESKEW_STEPS steps
    for _ in range(DESKEW_STEPS):
        s.observe((2.5, 0.0, 0.1), 0.25)  # 10 m/s forward, 0.4 rad/s
    vx, vy, wz = s.stream_twist(sweep())
    # forward in the vehicle's frame is −y in a radar mounted turned +90°
    assert (vx, vy, wz) == pytest.approx((0.0, -10.0, 0.4), abs=1e-9)
    s.forget_motion()
    assert s.stream_twist(sweep()) is None


def test_the_pair_keeps_the_references_twist_until_the_stream_moves_away():
    s, calls = stage()
    for _ in range(DESKEW_STEPS):
        s.observe((2.5, 0.0, 0.0), 0.25)
    ref = reference(sweep(), (10.0, 0.0, 0.0))
    assert s.pair_twist(sweep(250_000), ref) == (10.0, 0.0, 0.0) and not calls  # the same velocity: nothing redrawn
    for _ in range(DESKEW_STEPS):
        s.observe((5.0, 0.0, 0.0), 0.25)  # now 20 m/s: a pixel and more apart over a sweep
    assert s.pair_twist(sweep(250_000), ref) == (20.0, 0.0, 0.0)
    assert calls == [(ref.scan, (20.0, 0.0, 0.0))] and s.redraws == 1 and ref.twist == (20.0, 0.0, 0.0)
    assert ref.feed is not None and ref.feed[0] == 1.0  # the redrawn state is the reference's now


def test_a_failed_redraw_keeps_the_references_twist_and_still_counts():
    s, calls = stage(redraw_ok=False)
    for _ in range(DESKEW_STEPS):
        s.observe((5.0, 0.0, 0.0), 0.25)
    ref = reference(sweep(), (10.0, 0.0, 0.0))
    assert s.pair_twist(sweep(250_000), ref) == (10.0, 0.0, 0.0)
    assert len(calls) == 1 and s.redraws == 1 and ref.twist == (10.0, 0.0, 0.0) and ref.feed[0] == 0.0


def test_the_first_match_is_drawn_again_with_the_velocity_it_measured():
    s, calls = stage()
    ref = reference(sweep(), None)
    rematched = []
    out = Match(np.array([2.5, 0.0, 0.0]), np.eye(3), None, 0.0, 1)
    again = (np.array([2.6, 0.0, 0.0]), np.eye(3))
    got, twist = s.first_match(sweep(250_000), ref, 0.25, out, None, lambda tw: rematched.append(tw) or again)
    assert got is again and twist == pytest.approx((10.0, 0.0, 0.0))
    assert rematched == [twist] and calls[0][1] == twist and s.redraws == 1
    # a rematch that is not finite: no match at all (the reference stays redrawn)
    s2, _ = stage()
    assert s2.first_match(sweep(250_000), reference(sweep(), None), 0.25, out, None, lambda tw: None) == (None, None)


@pytest.mark.parametrize("case", ["off", "has_twist", "has_motion", "no_match", "still"])
def test_other_steps_pass_through_the_first_match_untouched(case):
    s, calls = stage(enabled=case != "off")
    ref = reference(sweep(), None)
    out = Match(np.array([0.0 if case == "still" else 2.5, 0.0, 0.0]), np.eye(3), None, 0.0, 1)
    twist = (10.0, 0.0, 0.0) if case == "has_twist" else None
    if case == "has_motion":
        s.observe((2.5, 0.0, 0.0), 0.25)
    if case == "no_match":
        out = None
    got = s.first_match(sweep(250_000), ref, 0.25, out, twist, lambda tw: pytest.fail("no second match"))
    assert got[0] is out and got[1] == twist and not calls and s.redraws == 0


def test_off_draws_nothing():
    s, calls = stage(enabled=False)
    s.observe((5.0, 0.0, 0.0), 0.25)
    ref = reference(sweep(), (10.0, 0.0, 0.0))
    assert s.pair_twist(sweep(250_000), ref) is None and s.stream_twist(sweep()) is None and not calls
