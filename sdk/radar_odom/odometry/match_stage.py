"""The predict and match stages of a stream: the new sweep matched against the reference.

`MatchStage.match` gives a `Match` (pose, covariance, new reference, its turn, the periods the step spans,
flags) of the new sweep against the reference sweep, or None where the graph's output is not finite. Poses
leave it in the vehicle's frame: a model with a mount yaw (``ModelInfo.mount_yaw_rad``, `radar-odom adapt`)
has its matches turned by it.

The match decides (docs/gaps.md, docs/time-base.md). Every step is first matched as the graph reads it, the
window where the graph puts it (`match_plain`; with ``centre_yaw`` the new sweep drawn turned by the
predicted yaw). Where that match is readable (sharp, not on the window's edge: `readable`) and agrees with
one period of motion per sweep (`agrees`), nothing was dropped, whatever the stamps say (a late stamp, a
stall, a catch-up). Where the stamps put no dropped sweep there, the match is the step as it is (the motion
prior's gate judges it). Where they do, the step is a gap crossing (`cross_gap`):

1. the match with the window centred on the prediction over the stamps' periods (the last velocity held
   as an arc, `gaps.crossing_prior`) and the plain match read the same motion from two window placements,
   the gap's prior allows it and a car could drive it (`gaps.drivable`): the step, flagged ``gap``;
2. else, flagged ``uncertain`` with the gap prior's covariance added to what it reports (``Match.cover``):
   the centred match where a match centred on it finds it again (two graph calls), else what the readings
   from several window centres agree on (``GapConfig.cross``; `gaps.crossing_readings`, `gaps.consensus`),
   else the centred match, else the plain one; each only where the gap's prior allows it and a car could
   drive it (near the arc its yaw makes, `gaps.off_the_arc`, at a yaw rate it can reach, `gaps.drivable`):
   a gap prediction does not replace a sharp match without evidence;
3. else the plain match where it lies within the motion prior's gate of one period a sweep (the stamps were
   late after all), flagged ``uncertain``; else the prediction, flagged ``uncertain``, ``gated`` and
   ``prior_dominated``.

The plain mode (``match_decides`` False) matches with the window centred on the stamps' prediction where they
say sweeps were dropped, else where the graph puts it, and takes that match as it is.

`MatchStage.readings_around` (the new sweep matched with the window centred around a pose) is the gap
crossing's search. The stage calls the model's `GraphStep` itself; the stream's state (the `Reference`)
comes with each call, and the odometer's `MotionPrior` is read, never changed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..se2 import invert, se2, to_xyyaw, turn_frame
from . import gaps
from .centring import MAX_TURN_RAD, next_turn, uncentre
from .motion_prior import GATED, PRIOR_DOMINATED, innovation, mahalanobis_d2
from .sweep_input import SweepMotion, graph_input

NO_AGREEMENT = object()  # `MatchStage._agreed`: the readings agreed on nothing the gap's prior allows
UNCERTAIN = "uncertain"
# Where the stamps say sweeps were dropped, a readable match overrules them only within χ²₃ at 95 % of one
# period of motion a sweep (the motion prior's gate, 99.9 %, let a wrong peak 0.8 m short of a 1.5 m step
# read a 7-period gap as no gap: a 6-sweep crossing of a 13° bend, seed 10000 of tests/test_deskew_gaps.py)
NOTHING_DROPPED_D2 = 7.81
# A plain match confirms a crossing only from the inner part of its window (this fraction of the half-width and
# of the yaw range): a peak near the window's edge is pulled inward, toward the centre it was drawn at
# (docs/yaw-precision.md), and one read there agreed with the centred match on a 4-sweep crossing 0.86 m short
# (fresh junction drive 349864205, benchmarks/do_no_harm.py): such a crossing is flagged uncertain instead
CONFIRM_FRACTION = 0.6  # a crossing no single readable match confirmed: its covariance covers the gap's prior


@dataclass
class Match:
    """One step's match: ``pose`` (x m, y m, yaw rad; vehicle frame) of the new sweep in the reference's
    frame with its ``cov`` [3, 3]; ``new_ref`` the new sweep as the graph's next reference (drawn in its own
    frame, turned by ``turn``); ``periods`` the sensor periods the step spans; ``flags`` the stage's verdict;
    ``cover`` [3, 3] or None: added to the reported covariance (an uncertain crossing)."""

    pose: np.ndarray
    cov: np.ndarray
    new_ref: np.ndarray
    turn: float
    periods: int
    flags: frozenset = field(default_factory=frozenset)
    cover: np.ndarray | None = None


class MatchStage:
    """How a new sweep is matched against the reference (see the module docstring).

    Args:
        graph: the model's `GraphStep` (``first``: a sweep made a reference; ``match``: a sweep against one).
        info: the model's `ModelInfo` (its profile: the window, the agreement tolerances; its mount yaw: the
            radar's frame turned into the vehicle's; its form and input: whether sweeps can be drawn moved).
        config: the odometer's `OdometerConfig` (``time``, ``gaps``, ``deskew.centre_yaw``).
        prior: the odometer's `MotionPrior` (its velocity predicts the motion; read only).

    Each call takes the stream's `Reference` (its state, the sweep as recorded, the turn and twist it was
    drawn with); the stage keeps nothing of a stream.
    """

    def __init__(self, graph, info, config, prior):
        self.graph = graph
        self.info = info
        self.profile = profile = info.profile
        self.mount_yaw_rad = info.mount_yaw_rad
        # a polar model's graph reads the sweep as recorded, a sweep-form graph draws it as recorded: neither
        # can be drawn moved (no centring, crossing or de-skew)
        self.movable = profile.input_kind != "polar" and info.form != "sweep"
        self.centre_yaw = config.deskew.centre_yaw and self.movable
        self.period_s = config.time.prior_period_s
        self.match_decides = config.time.match_decides
        self.cross = config.gaps.cross and self.movable
        self.max_yaw_accel = config.gaps.max_yaw_accel_rps2
        self._gate_d2 = (config.prior or prior.config).gate_d2
        self._prior = prior
        self._window_m = profile.translation_cells * profile.resolution_m
        self._sharp_m = gaps.agreement(profile)[2]

    def draw(self, scan, motion: SweepMotion | None = None):
        """The graph input of ``scan`` drawn with ``motion`` (`sweep_input.graph_input`)."""
        return graph_input(scan, self.info, motion)

    def match(self, scan, x: np.ndarray, twist, ref, sweeps: int, stamp_periods: int, lead_s: float,
              recent_yaw_rates=()) -> Match | None:
        """The `Match` of the new sweep (graph input ``x``, drawn with ``twist``) against the reference ``ref``
        (a `Reference`) ``sweeps`` sweeps back, the stamps putting ``stamp_periods`` periods between them;
        ``lead_s``: seconds from the end of the velocity's interval to the reference; ``recent_yaw_rates``:
        the yaw rates (rad/s) of the last second's steps. None where the graph's output is not finite."""
        k_stamp = max(int(sweeps), int(stamp_periods))
        by_stamps = self.movable and self._prior.ready and k_stamp > sweeps
        if by_stamps and not self.match_decides:  # plain: the window where the stamps' prediction puts it
            pred = gaps.crossing_prior(*self.prior_step(), k_stamp * self.period_s, lead_s)
            centred = self.centred(scan, twist, pred[0], ref)
            new_ref = None if centred is None else self.graph.first(x)
            if centred is not None and np.all(np.isfinite(new_ref)):
                return Match(centred[0], centred[1], new_ref, 0.0, k_stamp, frozenset({gaps.GAP}))
        plain = self.match_plain(scan, x, twist, ref, sweeps * self.period_s, lead_s)
        if plain is None:
            return None
        pose, cov, new_ref, turn = plain
        residual = turn_frame(pose, None, -self.mount_yaw_rad)[0] - (0.0, 0.0, turn - ref.turn)
        readable = self.readable(residual, cov)
        if not (self.match_decides and self._prior.ready):
            return Match(pose, cov, new_ref, turn, k_stamp, frozenset({gaps.GAP} if k_stamp > sweeps else ()))
        if readable and self.agrees(pose, cov, sweeps, lead_s, NOTHING_DROPPED_D2 if by_stamps else self._gate_d2):
            # one period a sweep: nothing was dropped, whatever the stamps say. Where their motion lies beyond what
            # this window could see and a match centred there reads it too, the two readings disagree on what
            # happened: the match stands (a stall's late stamp moves no pose), flagged uncertain with a covariance
            # that spans both (a repeating street read a 2 m step where 8 sweeps, 18 m, had been dropped: fresh
            # junction drive 1012826702, benchmarks/do_no_harm.py; taking the centred reading instead made a long
            # stall a phantom 8 m crossing on another fresh drive)
            if by_stamps and self.beyond_window(k_stamp, lead_s):
                pred = gaps.crossing_prior(*self.prior_step(), k_stamp * self.period_s, lead_s)
                seen = self.centred(scan, twist, pred[0], ref)
                if self.plausible(seen, pred, k_stamp * self.period_s, recent_yaw_rates):
                    d = innovation(seen[0], pose)
                    return Match(pose, cov, new_ref, turn, sweeps, frozenset({UNCERTAIN}), np.outer(d, d) + seen[1])
            return Match(pose, cov, new_ref, turn, sweeps)
        if not by_stamps:
            return Match(pose, cov, new_ref, turn, k_stamp)
        plain = (pose, cov) if readable else None
        inner = readable and self.readable(residual, cov, CONFIRM_FRACTION)
        return self.cross_gap(scan, twist, ref, k_stamp, lead_s, new_ref, recent_yaw_rates, plain, inner, sweeps)

    def beyond_window(self, periods: int, lead_s: float) -> bool:
        """Whether the gap prediction over ``periods`` periods lies beyond what a window at identity reads
        (`gaps.at_window_edge`): a motion the plain match could not have seen."""
        pred = gaps.crossing_prior(*self.prior_step(), periods * self.period_s, lead_s)[0]
        return gaps.at_window_edge(turn_frame(pred, None, -self.mount_yaw_rad)[0], self._window_m,
                                   self.profile.rotation_range_rad)

    def plausible(self, reading, pred, interval_s: float, recent_yaw_rates=()) -> bool:
        """Whether a crossing ``reading`` (pose, cov) is one to take: within the gate of the gap's prior
        ``pred``, near the arc a car drives with its yaw (`gaps.off_the_arc`), at a yaw rate it can reach from
        the last second's (`gaps.drivable`)."""
        return (reading is not None and gaps.crossing_d2(*reading, *pred) <= self._gate_d2
                and not gaps.off_the_arc(*reading)
                and gaps.drivable(*reading, interval_s, recent_yaw_rates, self.max_yaw_accel))

    def readable(self, residual, cov, fraction: float = gaps.EDGE_FRACTION) -> bool:
        """Whether a match's residual (radar frame, in the window it was drawn in) lies within ``fraction``
        of the window (`gaps.at_window_edge`) and its translation is sharp (`gaps.is_sharp` within the
        crossing's `SHARP_CELLS`)."""
        return (not gaps.at_window_edge(residual, self._window_m, self.profile.rotation_range_rad, fraction)
                and gaps.is_sharp(cov, self._sharp_m))

    def agrees(self, pose, cov, periods: int, lead_s: float, max_d2: float) -> bool:
        """Whether a match (pose, cov) lies within ``max_d2`` (d²) of the prediction over ``periods`` periods:
        the motion prior's for consecutive sweeps, the gap's (`gaps.crossing_prior`) across dropped ones."""
        interval_s = periods * self.period_s
        pred = (self._prior.predict(interval_s, lead_s) if periods == 1
                else gaps.crossing_prior(*self.prior_step(), interval_s, lead_s))
        return mahalanobis_d2(innovation(pose, pred[0]), np.asarray(cov) + pred[1]) <= float(max_d2)

    def centred(self, scan, twist, predicted, ref):
        """(pose, cov) of one match with the window centred on ``predicted`` (vehicle frame), or None where
        it is not finite or not readable."""
        a_ref = ref.turn
        centre = to_xyyaw(se2(0.0, 0.0, -a_ref) @ se2(*turn_frame(predicted, None, -self.mount_yaw_rad)[0]))
        drawn = self.draw(scan, SweepMotion(twist=twist, frame_pose=tuple(to_xyyaw(invert(se2(*centre))))))
        out = self.graph.match(drawn, ref.feed, True)
        if out is None or not self.readable(out[0], out[1]):
            return None
        moved = gaps.compose_residual(out[0], out[1], centre)
        return turn_frame(*uncentre(*moved, a_ref, 0.0), self.mount_yaw_rad)

    def cross_gap(self, scan, twist, ref, periods: int, lead_s: float, new_ref, recent_yaw_rates=(),
                  plain=None, plain_inner: bool = False, sweeps: int = 1) -> Match:
        """The `Match` of a step the stamps put ``periods`` periods after the reference and the plain match did
        not read as consecutive (steps 1-3 of the module docstring); ``new_ref``: the new sweep in its own frame
        (the plain match's); ``plain``: (pose, cov) of the plain match where it was readable, else None;
        ``plain_inner``: it lies within `CONFIRM_FRACTION` of its window (it may confirm the centred match);
        ``sweeps``: the sweeps since the reference (the periods were nothing dropped).

        Confident (flagged ``gap`` only) where the match centred on the prediction and the plain match read the
        same motion from two window placements, a car could drive it and the gap's prior allows it. Otherwise,
        flagged ``uncertain`` with the gap prior's covariance added: what the readings from several centres
        agree on, else the centred match, else the plain one (a gap prediction does not replace a sharp match
        without evidence), else the prediction (``gated``)."""
        interval_s = periods * self.period_s
        pred = gaps.crossing_prior(*self.prior_step(), interval_s, lead_s)

        def plausible(reading):
            return self.plausible(reading, pred, interval_s, recent_yaw_rates)

        centred = self.centred(scan, twist, pred[0], ref)
        tol_m, tol_rad, _ = gaps.agreement(self.profile)
        if (plausible(centred) and plain is not None and plain_inner
                and gaps.poses_agree(centred[0], plain[0], tol_m, tol_rad)):
            return Match(centred[0], centred[1], new_ref, 0.0, periods, frozenset({gaps.GAP}))
        uncertain = frozenset({gaps.GAP, UNCERTAIN})
        if plausible(centred):  # found again where it was found: a peak, not the window's centre (two calls)
            again = self.centred(scan, twist, centred[0], ref)
            if plausible(again) and gaps.poses_agree(again[0], centred[0], tol_m, tol_rad):
                return Match(again[0], again[1], new_ref, 0.0, periods, uncertain, pred[1])
        agreed = self._crossing(scan, twist, ref, pred, interval_s, plausible) if self.cross else None
        for reading in (agreed, centred, plain):
            if reading is not None and reading is not NO_AGREEMENT and plausible(reading):
                return Match(reading[0], reading[1], new_ref, 0.0, periods, uncertain, pred[1])
        if plain is not None and self.agrees(*plain, sweeps, lead_s, self._gate_d2):
            # no crossing reading holds, but the plain match is sharp and within the motion prior's gate of one
            # period a sweep: the stamps were late (a 1 s stall in a turn), the match decides (fresh junction
            # drive 847199047: the prediction, 8.1 m, had replaced a right 1.25 m match)
            return Match(plain[0], plain[1], new_ref, 0.0, sweeps, frozenset({UNCERTAIN}))
        # nothing read agrees with the gap's prior and a car's motion: the prediction
        return Match(pred[0], pred[1], new_ref, 0.0, periods, uncertain | {GATED, PRIOR_DOMINATED}, pred[1])

    def _crossing(self, scan, twist, ref, pred, interval_s: float, plausible):
        """(pose, cov) the readings from several window centres agree on, `NO_AGREEMENT`, or None where no
        match was finite. (Their de-skew by the crossing's own velocity, issue 41, was removed: on the host-clock
        rows it won no row, docs/scorecard.md.)"""
        agreed = self._agreed(self.readings_around(scan, twist, pred[0], ref), pred, plausible)
        return agreed if agreed is None or agreed is NO_AGREEMENT else (agreed[0], agreed[1])

    def match_plain(self, scan, x: np.ndarray, twist, ref, interval_s: float, lead_s: float):
        """(pose, cov, new reference, its turn) of one match of the new sweep against the reference as the
        graph reads it (drawn turned by the predicted yaw with ``centre_yaw``), or None if non-finite."""
        if self.centre_yaw:
            out = self.match_centred(scan, x, twist, ref, interval_s, lead_s)
            if out is None:
                return None
        else:
            out = self.graph.match(x, ref.feed)
            if out is None:
                return None
            out = (*out, 0.0)  # without centring every reference is drawn at turn 0
        mount = self.mount_yaw_rad
        if not mount:
            return out
        return (*turn_frame(out[0], out[1], mount), out[2], out[3])

    def _agreed(self, crossed, pred, plausible=None):
        """The readings' consensus (pose, cov, members) within the gap's prior ``pred``, readings off a road
        vehicle's arc left out (`gaps.off_the_arc`); `NO_AGREEMENT` where no centre agreed or they agree on a
        motion the prior rules out; None where no match was finite."""
        if crossed is None:
            return None
        crossed = [c for c in crossed if not gaps.off_the_arc(c[0], c[1])]  # not a motion a car makes
        tol_m, tol_rad, sharp_m = gaps.agreement(self.profile)
        agreed = gaps.consensus([c[0] for c in crossed], [c[1] for c in crossed], tol_m, tol_rad, sharp_m, prior=pred)
        if agreed is None or gaps.crossing_d2(agreed[0], agreed[1], *pred) > self._gate_d2:
            return NO_AGREEMENT
        if plausible is not None and not plausible(agreed[:2]):
            return NO_AGREEMENT
        return agreed

    def draw_reference(self, ref_scan, twist, ref_turn: float):
        """The reference state of ``ref_scan`` drawn with ``twist`` (and turned by ``ref_turn``), or None
        where the graph's output is not finite (one graph call): the de-skew stage's redraw."""
        turn = (0.0, 0.0, ref_turn) if ref_turn else None
        reference = self.graph.first(self.draw(ref_scan, SweepMotion(twist=twist, frame_pose=turn)))
        return reference if np.all(np.isfinite(reference)) else None

    def prior_step(self) -> tuple:
        """(pose, cov, s): the motion prior's velocity as a step over its interval."""
        p = self._prior
        return p.velocity * p.interval_s, p.velocity_covariance * p.interval_s ** 2, p.interval_s

    def readings_around(self, scan, twist, pose, ref, reference=None):
        """The new sweep's readings (pose, cov; vehicle frame) with the window centred around ``pose``
        (`gaps.crossing_readings`) against ``ref`` (a `Reference`, kept); None where no match was finite.
        ``reference``: another reference state to match against (drawn with the same ``twist``), or None
        for ``ref``'s."""
        a_ref, mount = ref.turn, self.mount_yaw_rad
        predicted = turn_frame(pose, None, -mount)[0]  # in the radar's frame, then the reference's drawn one
        centre = to_xyyaw(se2(0.0, 0.0, -a_ref) @ se2(*predicted))

        def residual_at(c):
            drawn = self.draw(scan, SweepMotion(twist=twist, frame_pose=tuple(to_xyyaw(invert(se2(*c))))))
            out = self.graph.match(drawn, ref.feed if reference is None else reference, True)
            return None if out is None else out[:2]

        readings = gaps.crossing_readings(centre, residual_at, self.profile)
        return None if readings is None else [turn_frame(*uncentre(*m, a_ref, 0.0), mount) for m in readings]

    def match_centred(self, scan, x: np.ndarray, twist, ref, interval_s: float, lead_s: float):
        """(pose in the radar's frame, cov, new reference, its turn) with the new sweep drawn turned
        by the predicted yaw, or None where the graph's output is not finite. A turn beyond
        `MAX_TURN_RAD` re-draws the new reference in its own frame (a second graph call)."""
        pred = self._prior.predict(interval_s, lead_s)
        a_ref = ref.turn
        a_new = next_turn(a_ref, None if pred is None else float(pred[0][2]))
        drawn = x if a_new == 0.0 else self.draw(scan, SweepMotion(twist=twist, frame_pose=(0.0, 0.0, a_new)))
        out = self.graph.match(drawn, ref.feed)
        if out is None:
            return None
        residual, residual_cov, new_ref = out
        pose, cov = uncentre(residual, residual_cov, a_ref, a_new)
        if abs(a_new) > MAX_TURN_RAD:
            new_ref, a_new = self.graph.first(x), 0.0
            if not np.all(np.isfinite(new_ref)):
                return None
        return pose, cov, new_ref, a_new
