"""The predict and match stages of a stream: the new sweep matched against the reference.

`MatchStage.match` gives (pose, cov, new reference, its turn[, flags]) of the new sweep against the
reference sweep, or None where the graph's output is not finite. Poses leave it in the vehicle's
frame: a model with a mount yaw (``ModelInfo.mount_yaw_rad``, `radar-odom adapt`) has its matches
turned by it. Three ways to match:

- across a gap (the reference further back than a gap, `gaps.SweepPeriod`, and the motion prior can
  predict the motion over it): the sweep matched from several window centres around the prediction
  (the last velocity held as an arc, `gaps.crossing_prior`), taken where the readings agree within
  the gap's prior, else the prediction, flagged ``gated`` and ``prior_dominated`` (docs/gaps.md); an
  agreed crossing is then matched once more with both sweeps de-skewed by the crossing's own velocity
  (``deskew_gaps``, `MatchStage.deskew_crossing`): over a gap the two sweeps' motion distortion does not
  cancel as it does between consecutive sweeps;
- with ``centre_yaw``: one match, the new sweep drawn turned by the predicted yaw
  (`radar_odom.odometry.centring`);
- otherwise one match of the sweep as drawn.

`MatchStage.readings_around` (the new sweep matched with the window centred around a pose) is also
what the time stage's whole periods decide a sweep's time with (`whole_periods.decide_time`).

The graph calls and the stream's state stay the odometer's: the stage takes the graph calls as
callables (``run_pair``, ``run_first``, ``sweep_input``) and each call the reference's turn and the
lead of the velocity's interval; it reads the odometer's `SweepPeriod` and `MotionPrior`, never
changes them.
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..se2 import invert, se2, to_xyyaw, turn_frame
from . import gaps
from .centring import MAX_TURN_RAD, next_turn, uncentre
from .motion_prior import GATED, PRIOR_DOMINATED
from .sweep_input import SweepMotion, deskew_twist

NO_AGREEMENT = object()  # `MatchStage._agreed`: the readings agreed on nothing the gap's prior allows
CROSSING_DESKEW_ROUNDS = 2  # de-skewed re-matches of an agreed crossing, each with the velocity of the one before


class MatchStage:
    """How a new sweep is matched against the reference: across a gap, centred on the predicted yaw, or plain.

    Args:
        profile: the model's `GridProfile` (the window, the readings' agreement tolerances).
        mount_yaw_rad: the model's mount yaw (``ModelInfo.mount_yaw_rad``): radar frame → vehicle's.
        movable: the model's sweeps can be drawn moved (not polar, not sweep form); else no gap crossing.
        centre_yaw: draw the new sweep turned by the predicted yaw (already False where not ``movable``).
        period: the odometer's `gaps.SweepPeriod` (what is a gap).
        prior: the odometer's `MotionPrior` (its velocity predicts the motion; read only).
        run_pair: ``(graph input, keep_reference=False) -> (pose, cov, new reference) or None``: the
            graph's match against the current reference (`GraphStep.match`).
        run_first: ``graph input -> reference state``: a sweep made a reference (`GraphStep.first`).
        sweep_input: ``(scan, SweepMotion) -> graph input``: the sweep drawn moved (`sweep_input.graph_input`).
        run_against: ``(graph input, reference state) -> (pose, cov, new reference) or None``: the graph's
            match against another reference than the current one (`GraphStep.match`); with ``deskew_gaps``.
        deskew_gaps: re-match an agreed gap crossing with both sweeps de-skewed by its own velocity
            (`deskew_crossing`); needs ``run_against`` and the reference sweep (``match(ref_scan=…)``).
    """

    def __init__(self, profile, mount_yaw_rad: float, movable: bool, centre_yaw: bool, period, prior,
                 run_pair: Callable, run_first: Callable, sweep_input: Callable,
                 run_against: Callable | None = None, deskew_gaps: bool = False):
        self.profile = profile
        self.mount_yaw_rad = mount_yaw_rad
        self.movable = bool(movable)
        self.centre_yaw = bool(centre_yaw)
        self._period = period
        self._prior = prior
        self._run_pair = run_pair
        self._run_first = run_first
        self._sweep_input = sweep_input
        self._run_against = run_against
        self.deskew_gaps = bool(deskew_gaps) and run_against is not None and self.movable

    def match(self, scan, x: np.ndarray, twist, interval_s: float, lead_s: float, ref_turn: float,
              ref_scan=None):
        """(pose, cov, new reference, its turn[, flags]) of the new sweep (graph input ``x``, drawn with
        ``twist``) against the reference ``interval_s`` back (drawn turned by ``ref_turn``; ``ref_scan``:
        that sweep as recorded, for the de-skewed crossing), or None if non-finite; ``lead_s``: seconds
        from the end of the velocity's interval to the reference.
        Across a gap the prior can predict, `cross_gap`; else one match (`match_plain`)."""
        if self.movable and self._period.is_gap(interval_s) and self._prior.ready:
            pred = gaps.crossing_prior(*self.prior_step(), interval_s, lead_s)
            if pred is not None:
                return self.cross_gap(scan, x, twist, pred, ref_turn, ref_scan, interval_s)
        return self.match_plain(scan, x, twist, interval_s, lead_s, ref_turn)

    def match_plain(self, scan, x: np.ndarray, twist, interval_s: float, lead_s: float, ref_turn: float):
        """(pose, cov, new reference, its turn) of one match of the new sweep against the reference
        (drawn turned by the predicted yaw with ``centre_yaw``), or None if non-finite."""
        if self.centre_yaw:
            out = self.match_centred(scan, x, twist, interval_s, lead_s, ref_turn)
            if out is None:
                return None
        else:
            out = self._run_pair(x)
            if out is None:
                return None
            out = (*out, 0.0)  # without centring every reference is drawn at turn 0
        mount = self.mount_yaw_rad
        if not mount:
            return out
        return (*turn_frame(out[0], out[1], mount), out[2], out[3])

    def cross_gap(self, scan, x: np.ndarray, twist, pred, ref_turn: float, ref_scan=None,
                  interval_s: float | None = None):
        """(pose, cov, new reference, 0.0[, flags]) of a sweep across a gap, ``pred`` the gap's prior
        (pose, cov): the sweep matched from several window centres around the prediction
        (`gaps.crossing_readings`); taken where readings agree within the prior (`gaps.consensus`,
        `gaps.crossing_d2`), else the prediction, flagged ``gated`` and ``prior_dominated``. An agreed
        crossing is matched again de-skewed (`deskew_crossing`) where ``deskew_gaps`` and ``ref_scan``
        (the reference as recorded) and ``interval_s`` are given. None where no match is finite or the
        new reference is not. The new reference is the sweep in its own frame (drawn with ``twist``)."""
        deskew = self.deskew_gaps and ref_scan is not None and bool(interval_s)
        drawn_with, reference = twist, None
        if deskew:
            # the readings drawn de-skewed by the prediction's velocity (the reference redrawn with it)
            radar = turn_frame(np.asarray(pred[0], dtype=np.float64), None, -self.mount_yaw_rad)[0]
            predicted = deskew_twist(gaps.crossing_velocity(radar, interval_s), scan, self.profile)
            reference = None if predicted is None else self.draw_reference(ref_scan, predicted, ref_turn)
            drawn_with = twist if reference is None else predicted
        agreed = self._agreed(self.readings_around(scan, drawn_with, pred[0], ref_turn, reference), pred)
        if reference is not None and (agreed is None or agreed is NO_AGREEMENT):
            # the readings drawn de-skewed found nothing to agree on: the readings as recorded, as before
            agreed = self._agreed(self.readings_around(scan, twist, pred[0], ref_turn), pred)
        if agreed is None:
            return None
        new_ref = self._run_first(x)
        if not np.all(np.isfinite(new_ref)):
            return None
        if agreed is NO_AGREEMENT:
            # no centre agreed, or they agree on a motion the gap's prior rules out: keep the prediction
            return pred[0], pred[1], new_ref, 0.0, {GATED, PRIOR_DOMINATED}
        if deskew:
            pose = self.deskew_crossing(scan, ref_scan, agreed[0], interval_s, ref_turn)
            if pose is not None and gaps.crossing_d2(pose, agreed[1], *pred) <= self._prior.config.gate_d2:
                return pose, agreed[1], new_ref, 0.0
        return agreed[0], agreed[1], new_ref, 0.0

    def _agreed(self, crossed, pred):
        """The readings' consensus (pose, cov, members) within the gap's prior ``pred``, readings off a road
        vehicle's arc left out (`gaps.off_the_arc`); `NO_AGREEMENT` where no centre agreed or they agree on a
        motion the prior rules out; None where no match was finite."""
        if crossed is None:
            return None
        crossed = [c for c in crossed if not gaps.off_the_arc(c[0], c[1])]  # not a motion a car makes
        tol_m, tol_rad, sharp_m = gaps.agreement(self.profile)
        agreed = gaps.consensus([c[0] for c in crossed], [c[1] for c in crossed], tol_m, tol_rad, sharp_m, prior=pred)
        if agreed is None or gaps.crossing_d2(agreed[0], agreed[1], *pred) > self._prior.config.gate_d2:
            return NO_AGREEMENT
        return agreed

    def deskew_crossing(self, scan, ref_scan, pose, interval_s: float, ref_turn: float):
        """The crossing ``pose`` (x m, y m, yaw rad; vehicle frame) matched again with both sweeps
        de-skewed by its own velocity, or None (nothing to de-skew, a match not finite or at the
        window's edge, or one that moved away from ``pose`` beyond the readings' agreement).

        Between consecutive sweeps drawn alike the motion during each sweep distorts both the same way
        and cancels in the match; across a gap the reference and the new sweep see the scene from poses
        metres and degrees apart, so it does not (a 6-sweep gap in a 13° bend, cart-0.4, one match at the
        true pose: 0.13 m / 0.31° median error as recorded, 0.05 m / 0.15° with both sweeps de-skewed by
        the true velocity; docs/gaps.md). The velocity is the crossing's own (``se2_log(pose) /
        interval_s``, constant over the gap), not the stream's: the steps before a gap in a bend read it
        short. `CROSSING_DESKEW_ROUNDS` rounds, each a reference redrawn and one match centred on the pose
        of the round before (two graph calls a round)."""
        mount, a_ref = self.mount_yaw_rad, ref_turn
        tol_m, tol_rad, _ = gaps.agreement(self.profile)
        window_m = self.profile.translation_cells * self.profile.resolution_m
        start = radar = turn_frame(np.asarray(pose, dtype=np.float64), None, -mount)[0]  # the radar's frame
        for _ in range(CROSSING_DESKEW_ROUNDS):
            twist = deskew_twist(gaps.crossing_velocity(radar, interval_s), scan, self.profile)
            reference = None if twist is None else self.draw_reference(ref_scan, twist, a_ref)
            if reference is None:
                return None
            centre = to_xyyaw(se2(0.0, 0.0, -a_ref) @ se2(*radar))  # in the reference's drawn frame
            drawn = self._sweep_input(scan, SweepMotion(twist=twist, frame_pose=tuple(to_xyyaw(invert(se2(*centre))))))
            out = self._run_against(drawn, reference)
            if out is None or gaps.at_window_edge(out[0], window_m, self.profile.rotation_range_rad):
                return None
            moved, _ = gaps.compose_residual(out[0], out[1], centre)
            radar = uncentre(moved, np.zeros((3, 3)), a_ref, 0.0)[0]
        if not gaps.poses_agree(radar, start, 2.0 * tol_m, 2.0 * tol_rad):
            return None  # a de-skewed match that moved that far found another peak, not the same one sharper
        return turn_frame(radar, None, mount)[0]

    def draw_reference(self, ref_scan, twist, ref_turn: float):
        """The reference state of ``ref_scan`` drawn with ``twist`` (and turned by ``ref_turn``), or None
        where the graph's output is not finite (one graph call). Also the de-skew stage's redraw."""
        turn = (0.0, 0.0, ref_turn) if ref_turn else None
        reference = self._run_first(self._sweep_input(ref_scan, SweepMotion(twist=twist, frame_pose=turn)))
        return reference if np.all(np.isfinite(reference)) else None

    def prior_step(self) -> tuple:
        """(pose, cov, s): the motion prior's velocity as a step over its interval."""
        p = self._prior
        return p.velocity * p.interval_s, p.velocity_covariance * p.interval_s ** 2, p.interval_s

    def readings_around(self, scan, twist, pose, ref_turn: float, reference=None):
        """The new sweep's readings (pose, cov; vehicle frame) with the window centred around ``pose``
        (`gaps.crossing_readings`), the reference (drawn turned by ``ref_turn``) kept; None where no
        match was finite. ``reference``: another reference state to match against (drawn with the same
        ``twist``), or None for the current one."""
        a_ref, mount = ref_turn, self.mount_yaw_rad
        predicted = turn_frame(pose, None, -mount)[0]  # in the radar's frame, then the reference's drawn one
        centre = to_xyyaw(se2(0.0, 0.0, -a_ref) @ se2(*predicted))

        def residual_at(c):
            drawn = self._sweep_input(scan, SweepMotion(twist=twist, frame_pose=tuple(to_xyyaw(invert(se2(*c))))))
            if reference is None:
                out = self._run_pair(drawn, keep_reference=True)
            else:
                out = self._run_against(drawn, reference)
            return None if out is None else out[:2]

        readings = gaps.crossing_readings(centre, residual_at, self.profile)
        return None if readings is None else [turn_frame(*uncentre(*m, a_ref, 0.0), mount) for m in readings]

    def match_centred(self, scan, x: np.ndarray, twist, interval_s: float, lead_s: float, ref_turn: float):
        """(pose in the radar's frame, cov, new reference, its turn) with the new sweep drawn turned
        by the predicted yaw, or None where the graph's output is not finite. A turn beyond
        `MAX_TURN_RAD` re-draws the new reference in its own frame (a second graph call)."""
        pred = self._prior.predict(interval_s, lead_s)
        a_ref = ref_turn
        a_new = next_turn(a_ref, None if pred is None else float(pred[0][2]))
        drawn = x if a_new == 0.0 else self._sweep_input(scan, SweepMotion(twist=twist, frame_pose=(0.0, 0.0, a_new)))
        out = self._run_pair(drawn)
        if out is None:
            return None
        residual, residual_cov, new_ref = out
        pose, cov = uncentre(residual, residual_cov, a_ref, a_new)
        if abs(a_new) > MAX_TURN_RAD:
            new_ref, a_new = self._run_first(x), 0.0
            if not np.all(np.isfinite(new_ref)):
                return None
        return pose, cov, new_ref, a_new
