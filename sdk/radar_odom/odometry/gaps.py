"""Crossing a gap in a recording: dropped sweeps, a stalled driver, a bridged degenerate sweep.

Over a gap the car moves further than the graph's search window reaches (RADIATE drives hold
holes of 1.3–1.5 s, 10–16 m at city speed, against a ±8 m window), so a plain match clips
to the window's edge or locks onto a wrong peak. The odometer instead draws the new sweep in the
frame the motion prior predicts for it (`radar_odom.odometry.sweep_input.SweepMotion.frame_pose` =
P⁻¹), so the graph measures only the residual M of the prediction P, and composes the two:
the new sweep's pose in the reference frame is ``M ∘ P``, whose covariance is the residual's
carried through that composition (P is not uncertain there: it only placed the window).

Which step is a gap is the match's verdict (`radar_odom.odometry.match_stage`): the stamps give a count
of periods (`radar_odom.odometry.stream_time.StreamClock`), and a readable match that agrees with one
period a sweep overrules them.

The prediction over a gap (`crossing_prior`) is the last velocity held as a constant *twist*: an
arc, not the chord of one period scaled up (in a steady 13° bend the scaled chord puts the far
sweep ~0.6 m off to the outside of the turn). Its covariance grows with the gap: the velocity's
own, scaled, plus what sustained accelerations of a road vehicle do over the gap
(`GAP_ACCEL_STD`). The graph matches the new sweep from nine window centres around the prediction
(`crossing_centres`), and once more centred on each sharp reading it gave (`is_sharp`: a true peak
is found again where it is looked for); a match whose residual lies at the edge of the search
window is dropped (`at_window_edge`: a peak clipped by the window, nothing found inside it), and
readings a car could not have driven are dropped (`off_the_arc`: far sideways of the arc with their
yaw), and the crossing is taken only where at least two of these matches agree on the pose (`consensus`;
the largest such group, of equal ones the nearest the gap's prior) and that pose lies within the
χ² gate of the prior (`crossing_d2`).
Otherwise the odometer keeps the prediction with the prior's covariance, flagged ``"gated"``. Why
a single match can be wrong, measured: docs/gaps.md.
"""
from __future__ import annotations

import math

import numpy as np

from ..se2 import se2_exp, se2_log, wrap_angle

GAP = "gap"  # flag of an estimate whose step spans dropped sweeps (the match's verdict, `match_stage`)
NEW_SEGMENT = "new_segment"  # flag of the first sweep after a stamp jump no prediction can bridge
# Beyond this a constant-velocity prediction cannot place the ±8 m search window: its 4 m/s² spread
# alone is ½·a·t² = 200 m at 10 s (a one-hour stamp jump was extrapolated into a 24 km step). The
# stream starts a new segment there: the sweep is kept at the last pose, unrelated to it.
NEW_SEGMENT_GAP_S = 10.0
# 1σ of the accelerations a road vehicle *sustains* over a gap of a second or two: forward (m/s²),
# sideways (m/s²), yaw (rad/s²). Smaller than the motion prior's per-step figures (4 m/s², 40 °/s²),
# which cover a jolt within one period; held over 1.75 s those would allow 7 m and 70°. A car
# brakes or accelerates at 1–2.5 m/s² (the simulator: 1.5 up, 2.5 down) and enters a turn at
# ≤ 30 °/s within ~2 s.
GAP_ACCEL_STD = (1.5, 1.0, math.radians(8.0))
# The crossing is matched from several window centres around the prediction: the prediction itself,
# then moved forward/back by this fraction of the window's half-width, and turned either way by 1, 2
# and 3 times this fraction of the yaw range (5°, 10°, 15° for the shipped ±15°). A true peak is
# found from several of them and composes to the same pose; a peak at the window's edge, or one the
# centring happened to fall near, moves with the centre.
HYPOTHESIS_SHIFT_FRACTION = 0.35
HYPOTHESIS_TURN_FRACTION = 0.33
# Crossings agree when their poses lie within these of each other (or within one grid cell and two
# yaw steps, for a coarser grid: `agreement`); a crossing is taken where at least CONSENSUS_COUNT of
# the centres agree (one centre alone is what failed before: a peak the centring fell near).
CONSENSUS_M = 0.5
CONSENSUS_RAD = math.radians(1.0)
CONSENSUS_COUNT = 2
# A crossing counts toward the consensus only where the graph is sure of it within this many grid
# cells (translation σ; 0.8 m for cart-0.4): the wrong peaks of a tightening turn (docs/gaps.md)
# spread 0.9–4.6 m along the road, the right ones mostly 0.3–0.5 m (4 cells let wrong pairs in).
SHARP_CELLS = 2.0
# A road vehicle crosses a gap along something close to an arc: a rear axle following a circle ends
# on the chord turned by half its yaw, so its sideways distance from that chord is zero. What a sensor
# on a real car adds: its lever arm ahead of the axle sways by about arm × yaw (`ARC_LEVER_M`, a
# roof-mounted radar is within 2.5 m of it), and a turn that tightens over the gap (a clothoid from
# straight turns its chord by a third of the yaw, not half) about |x| × yaw / 6 (`ARC_CHORD_FRACTION`
# allows a quarter); `ARC_BASE_M` for the rest (the simulated tightening turn that ends 16° round sits
# 0.13 m off; its wrong reading sits 4.0 m off, docs/gaps.md). A reading further off than that plus
# three of its own σ is not a motion the car made (`off_the_arc`) and does not count toward a crossing.
ARC_BASE_M = 0.5
ARC_LEVER_M = 2.5
ARC_CHORD_FRACTION = 0.25
ARC_SD = 3.0
# A residual beyond this fraction of the search window's half-width (translation, each axis) or
# of its yaw range sits on the window's edge: the softmax read-out of a peak outside the window.
EDGE_FRACTION = 0.85


def compose_residual(residual, residual_cov, predicted) -> tuple[np.ndarray, np.ndarray]:
    """(pose float64[3], covariance float64[3, 3]) of ``M ∘ P`` from a measured residual M.

    Args:
        residual: float[3] (x m, y m, yaw rad) M: the pose of the frame the new sweep was drawn
            in (the reference frame moved by the residual) — what the graph measured.
        residual_cov: float[3, 3] its covariance.
        predicted: float[3] P: the prediction the new sweep was drawn against (its frame in the
            drawn frame is P; the sweep was drawn with ``frame_pose = P⁻¹``).

    Returns the new sweep's pose in the reference frame, ``t = t_M + R(yaw_M)·t_P``, ``yaw =
    yaw_M + yaw_P`` (wrapped), and ``J·C·Jᵀ`` with J the Jacobian of that map in M: a yaw
    uncertainty of the residual swings the predicted translation, so it grows the covariance
    across the direction of travel.
    """
    mx, my, myaw = (float(v) for v in np.asarray(residual, dtype=np.float64).reshape(3))
    px, py, pyaw = (float(v) for v in np.asarray(predicted, dtype=np.float64).reshape(3))
    c, s = math.cos(myaw), math.sin(myaw)
    yaw = math.atan2(math.sin(myaw + pyaw), math.cos(myaw + pyaw))
    pose = np.array([mx + c * px - s * py, my + s * px + c * py, yaw])
    jac = np.array([[1.0, 0.0, -s * px - c * py], [0.0, 1.0, c * px - s * py], [0.0, 0.0, 1.0]])
    cov = jac @ np.asarray(residual_cov, dtype=np.float64).reshape(3, 3) @ jac.T
    return pose, 0.5 * (cov + cov.T)


def crossing_prior(step_pose, step_cov, step_s: float, interval_s: float, lead_s: float = 0.0):
    """(pose float64[3], covariance float64[3, 3]) predicted over a gap of ``interval_s`` seconds.

    Args:
        step_pose: float[3] (x m, y m, yaw rad) the last measured relative pose, over ``step_s``
            seconds (the motion prior's velocity times its interval).
        step_cov: float[3, 3] its covariance.
        step_s: that pose's interval, s (> 0).
        interval_s: the gap's interval, s (> 0).
        lead_s: seconds from the end of the step's interval to the start of the gap's.

    The pose is the step's constant twist held over the gap, ``exp((interval/step) · log(step))``
    (`radar_odom.se2.se2_exp`): a circular arc. The covariance is the step's scaled by
    ``k = interval/step`` squared (first order, the arc's Jacobian taken as k·I: the twist's
    error is what grows) plus ``(σ_a · τ · interval)²`` per component with τ = step/2 + lead +
    interval/2, the time between the middles of the two intervals (as the motion prior's process
    noise, `radar_odom.odometry.motion_prior.MotionPriorConfig.process_noise`), σ_a
    `GAP_ACCEL_STD`. It grows with the gap, about as its square.
    """
    step_s, interval_s = float(step_s), float(interval_s)
    if not (step_s > 0 and interval_s > 0):
        raise ValueError(f"step_s and interval_s must be positive, got {step_s!r}, {interval_s!r}")
    k = interval_s / step_s
    pose = se2_exp(k * se2_log(step_pose))
    tau = 0.5 * step_s + max(float(lead_s), 0.0) + 0.5 * interval_s
    q = np.diag((np.asarray(GAP_ACCEL_STD) * tau * interval_s) ** 2)
    cov = k * k * np.asarray(step_cov, dtype=np.float64).reshape(3, 3) + q
    return pose, 0.5 * (cov + cov.T)


def at_window_edge(residual, window_m: float, yaw_range_rad: float, fraction: float = EDGE_FRACTION) -> bool:
    """Whether a residual (x m, y m, yaw rad) lies on the search window's edge: |x| or |y| beyond
    ``fraction`` × ``window_m`` (the ±half-width), or |yaw| beyond ``fraction`` × ``yaw_range_rad``."""
    r = np.asarray(residual, dtype=np.float64).reshape(3)
    return bool(max(abs(r[0]), abs(r[1])) > fraction * float(window_m)
                or abs(float(wrap_angle(r[2]))) > fraction * float(yaw_range_rad))


def crossing_d2(pose, cov, prior_pose, prior_cov) -> float:
    """Innovation d² of a crossing ``pose`` (cov) against the gap's prior: ``rᵀ (C + C_p)⁻¹ r``,
    r = pose − prior with the yaw wrapped."""
    r = np.asarray(pose, dtype=np.float64).reshape(3) - np.asarray(prior_pose, dtype=np.float64).reshape(3)
    r[2] = float(wrap_angle(r[2]))
    s = np.asarray(cov, dtype=np.float64).reshape(3, 3) + np.asarray(prior_cov, dtype=np.float64).reshape(3, 3)
    return float(r @ np.linalg.solve(0.5 * (s + s.T), r))


def crossing_centres(predicted, window_m: float, yaw_range_rad: float) -> list[np.ndarray]:
    """float64[3] poses to centre the search window on, the prediction first: ``P``, then ``P``
    moved along its x by ± `HYPOTHESIS_SHIFT_FRACTION` × ``window_m``, then turned by ±1, ±2 and ±3
    × `HYPOTHESIS_TURN_FRACTION` × ``yaw_range_rad`` (each an offset in the predicted frame:
    ``P ∘ δ``): nine centres, reaching twice the graph's yaw range either way (a junction turn that
    starts in the gap leaves a constant-velocity prediction far behind)."""
    from ..se2 import se2, to_xyyaw

    d, a = HYPOTHESIS_SHIFT_FRACTION * float(window_m), HYPOTHESIS_TURN_FRACTION * float(yaw_range_rad)
    p = se2(*np.asarray(predicted, dtype=np.float64).reshape(3))
    offsets = ((0.0, 0.0, 0.0), (d, 0.0, 0.0), (-d, 0.0, 0.0)) + tuple((0.0, 0.0, k * a) for k in (1, -1, 2, -2, 3, -3))
    return [to_xyyaw(p @ se2(*o)) for o in offsets]


def poses_agree(a, b, tol_m: float, tol_rad: float) -> bool:
    """Whether two poses (x m, y m, yaw rad) lie within ``tol_m`` of each other and their yaws within ``tol_rad``."""
    a, b = np.asarray(a, dtype=np.float64).reshape(3), np.asarray(b, dtype=np.float64).reshape(3)
    return bool(math.hypot(a[0] - b[0], a[1] - b[1]) <= tol_m and abs(float(wrap_angle(a[2] - b[2]))) <= tol_rad)


def crossing_velocity(pose, interval_s: float) -> np.ndarray:
    """float64[3] (vx m/s, vy m/s, yaw rate rad/s; the frame of ``pose``'s start): the constant body
    velocity that moves by ``pose`` (x m, y m, yaw rad) in ``interval_s`` (`se2_log` / interval)."""
    return se2_log(np.asarray(pose, dtype=np.float64).reshape(3)) / float(interval_s)


def arc_offset(pose) -> tuple[float, np.ndarray]:
    """(m, float64[3]): how far the end of ``pose`` (x m, y m, yaw rad; vehicle frame, x forward) lies
    sideways of the chord a circular arc with that yaw would end on (the line through the start at
    yaw/2: ``y·cos(yaw/2) − x·sin(yaw/2)``, positive to +y), and its gradient in (x, y, yaw)."""
    x, y, yaw = (float(v) for v in np.asarray(pose, dtype=np.float64).reshape(3))
    c, s = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return y * c - x * s, np.array([-s, c, -0.5 * (x * c + y * s)])


def off_the_arc(pose, cov) -> bool:
    """Whether a crossing ``pose`` (x m, y m, yaw rad; vehicle frame) with covariance ``cov`` [3, 3] lies
    sideways of the arc a road vehicle would drive with that yaw by more than the lever arm, a tightening
    turn and the rest allow plus `ARC_SD` of its own σ there (`ARC_BASE_M` and the constants beside it)."""
    offset, grad = arc_offset(pose)
    p = np.asarray(pose, dtype=np.float64).reshape(3)
    x, yaw = float(p[0]), abs(float(wrap_angle(p[2])))
    sd = math.sqrt(max(float(grad @ np.asarray(cov, dtype=np.float64).reshape(3, 3) @ grad), 0.0))
    allowed = ARC_BASE_M + (ARC_LEVER_M + ARC_CHORD_FRACTION * abs(x)) * yaw + ARC_SD * sd
    return abs(offset) > allowed


def agreement(profile) -> tuple[float, float, float]:
    """(m, rad, m) for `consensus` with a model of this `GridProfile`: crossings agree within
    `CONSENSUS_M` and `CONSENSUS_RAD` (or one grid cell and two yaw steps where those are coarser);
    a crossing counts where its translation σ is within `SHARP_CELLS` grid cells."""
    cell = float(profile.resolution_m)
    return max(CONSENSUS_M, cell), max(CONSENSUS_RAD, 2.0 * float(profile.rotation_step_rad)), SHARP_CELLS * cell


def is_sharp(cov, max_sd_m: float) -> bool:
    """Whether a match's translation σ (the larger of x and y, from its 3×3 ``cov``) is within ``max_sd_m``."""
    c = np.asarray(cov, dtype=np.float64).reshape(3, 3)
    return math.sqrt(max(c[0, 0], c[1, 1], 0.0)) <= float(max_sd_m)


def crossing_readings(predicted, residual_at, profile) -> list | None:
    """The gap crossing's readings: (pose float64[3], covariance float64[3, 3]) of the new sweep in the
    reference's drawn frame, one per match with the window centred on each of `crossing_centres`
    around ``predicted``, then once more on each sharp one (a true peak is found again where it is
    looked for; docs/gaps.md), the refined ones first, so a group's pose is one drawn at itself.
    Matches at the window's edge measured nothing inside it and are left out.

    Args:
        predicted: float[3] the prediction in the reference's drawn frame.
        residual_at: ``centre -> (residual, residual_cov) | None``: the graph's match of the new sweep
            drawn with ``frame_pose = centre⁻¹`` (None where its output is not finite).
        profile: the model's `GridProfile` (the window and the agreement scales).

    Returns the readings (possibly none), or None where no match at all was finite.
    """
    window_m = profile.translation_cells * profile.resolution_m
    _, _, sharp_m = agreement(profile)
    finite = False

    def reading(centre):
        nonlocal finite
        out = residual_at(centre)
        finite |= out is not None
        if out is None or at_window_edge(out[0], window_m, profile.rotation_range_rad):
            return None
        return compose_residual(out[0], out[1], centre)

    found = [m for m in map(reading, crossing_centres(predicted, window_m, profile.rotation_range_rad)) if m]
    refined = [m for m in map(reading, [f[0] for f in found if is_sharp(f[1], sharp_m)]) if m]
    return refined + found if finite else None


def consensus(poses, covariances, tol_m: float = CONSENSUS_M, tol_rad: float = CONSENSUS_RAD,
              max_sd_m: float = math.inf, min_count: int = CONSENSUS_COUNT, prior=None):
    """(pose float64[3], covariance float64[3, 3], members) of a group of crossings that agree, or
    None where no ``min_count`` of them do.

    Only sharp crossings count: those whose translation σ (the larger of x and y) is within
    ``max_sd_m`` (a peak spread along the road is the graph saying it does not know). A crossing's
    group: every counted crossing within ``tol_m`` (translation) and ``tol_rad`` (yaw) of it. Of the
    groups of at least ``min_count`` the largest wins; of equal ones, the likeliest under ``prior``
    ((pose, covariance): the gap's prior, its covariance alone), or without a prior the earlier.
    (Ranking every group by the prior instead let wrong pairs near it win: measured in docs/gaps.md.)
    The pose is the group's first member's (the
    centres come nearest the prediction first, and a match is pulled toward the centre it was drawn
    at: docs/yaw-precision.md), its covariance that member's plus the group's spread about it (the
    members match the same two sweeps: their errors are not independent, so no 1/n).
    """
    p = [np.asarray(x, dtype=np.float64).reshape(3) for x in poses]
    c = [np.asarray(x, dtype=np.float64).reshape(3, 3) for x in covariances]
    sharp = [j for j in range(len(p)) if is_sharp(c[j], max_sd_m)]
    groups = []
    for i in sharp:
        g = tuple(j for j in sharp if poses_agree(p[i], p[j], tol_m, tol_rad))
        if len(g) >= int(min_count) and g not in groups:
            groups.append(g)
    if not groups:
        return None
    means = [_group_mean(p, c, g) for g in groups]


    def rank(k):  # the largest group; of equal ones the likeliest under the prior's covariance alone
        near = crossing_d2(means[k][0], np.zeros((3, 3)), *prior) if prior is not None else float(k)
        return -len(groups[k]), near

    best = min(range(len(groups)), key=rank)
    return (*means[best], list(groups[best]))


def _group_mean(p, covariances, members) -> tuple[np.ndarray, np.ndarray]:
    pose = p[members[0]].copy()
    dev = np.array([p[j] for j in members]) - pose
    dev[:, 2] = wrap_angle(dev[:, 2])
    cov = np.asarray(covariances[members[0]], dtype=np.float64).reshape(3, 3) + dev.T @ dev / len(members)
    return pose, 0.5 * (cov + cov.T)


def drivable(pose, cov, interval_s: float, recent_yaw_rates, max_yaw_accel_rps2: float, sd: float = ARC_SD) -> bool:
    """Whether a car could have driven a crossing ``pose`` (x m, y m, yaw rad; covariance ``cov`` [3, 3]) in
    ``interval_s`` seconds, given the yaw rates (rad/s) of its last second (``recent_yaw_rates``; none: 0).

    Its mean yaw rate over the gap must lie within the band those rates span widened by what a yaw
    acceleration of ``max_yaw_accel_rps2`` adds on average over the gap (``a · interval / 2``: from the last
    rate, the rate grows by at most ``a · t``), plus ``sd`` of the reading's own yaw σ per interval. A turn
    that starts in the gap reaches its rate within the band; a wrong peak that reads a junction turn three
    times as sharp as any car makes it does not (issue 50: −73.5° read for +13.5° over 1.75 s)."""
    t = float(interval_s)
    rates = np.asarray(list(recent_yaw_rates) or [0.0], dtype=np.float64)
    yaw = float(wrap_angle(np.asarray(pose, dtype=np.float64).reshape(3)[2]))
    yaw_sd = math.sqrt(max(float(np.asarray(cov, dtype=np.float64).reshape(3, 3)[2, 2]), 0.0))
    slack = 0.5 * float(max_yaw_accel_rps2) * t + sd * yaw_sd / t
    rate = yaw / t
    return bool(rates.min() - slack <= rate <= rates.max() + slack)
