"""The time stage's whole periods: where a recording's stamps cannot place a sweep, the match does.

A recording's time base (`radar_odom.io.timebase.TimeBase`) puts every sweep on the sensor's period.
Two readings of the stamps it cannot tell apart, and what decides each here:

- **A drop before the sweep, or its stamp a period late and the drop after it.** Stamps
  ``…, t, t + 2P, t + 3P, …`` are one sweep dropped before the third on-time stamp, or the third stamp a
  whole period late with the next sweep dropped: the same stamps, an interval of 2P then P of motion,
  or P then 2P. The fit takes the first (fewer late stamps) and lists the second
  (`TimeBase.alternatives`). Here the sweep is matched with the search window centred around the
  motion prior's prediction over each reading's interval (`radar_odom.odometry.gaps.crossing_prior`:
  the last velocity held as an arc, its covariance grown with the interval; the window centres of a
  gap crossing, `radar_odom.odometry.gaps.crossing_readings`), the largest group of readings that
  agree is the motion (`radar_odom.odometry.gaps.consensus`), and the reading of the time whose
  prediction explains it best (`choose_hypothesis`: Gaussian log-likelihood, the match's covariance
  plus the prediction's) is the sweep's time from then on: the velocity, the gap flag and crossing,
  de-skew and the trajectory's time all use it (`SweepTimes.decide`). The evidence is the distance
  the car covers in one period: none at a standstill, and none where no two readings agree; there
  the fit's reading stays (`MIN_EVIDENCE`), listed as undecided.
- **P or P/2 for the whole recording** (every interval a whole multiple of both, no nominal period
  given). Every sweep's time is then the same under both: no match between two sweeps can tell them
  apart. What can is one sweep's own rotation time, where the format records each azimuth's time
  (Oxford, Boreas, the simulator): `rotation_period_s`, given to the fit as its period hint
  (`SweepTimes.adopt_rotation`). Where azimuth times are spread over the fitted period (RADIATE), they
  say nothing new, and the stamps' choice (the largest) stays.

Measured in docs/time-base.md.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import ConfigError
from ..io.timebase import TimeBase, fit_time_base
from ..scan import RadarScan
from .gaps import consensus, crossing_d2, crossing_prior

# log-likelihood ratio (nats) a reading must win by to replace the fit's: below it (a car nearly
# still, where one period moves it less than the match's own uncertainty) the fit's reading stays
MIN_EVIDENCE = 2.0
# a sweep's rotation time must lie within this fraction of a candidate period to pick it
ROTATION_TOLERANCE = 0.15
# The agreed motion must lie within χ²₃ at 95 % of the prediction it picks. A wrong peak the windows agree
# on (a standstill read in a 3°/sweep bend: seed 10044 of benchmarks/whole_periods.py, d² 9.6 under the
# shorter interval and 21 under the right one) is less unlikely under one reading, not likely under it;
# the right readings of those runs lay within d² 1.4 of their prediction.
DECISION_D2 = 7.81


def log_likelihood(pose, cov, pred_pose, pred_cov) -> float:
    """Gaussian log-likelihood (nats, less a constant) of a matched relative pose (x m, y m, yaw rad;
    float[3], covariance float[3, 3]) under a prediction (pose, covariance): ``−½ (rᵀ S⁻¹ r + ln|S|)``,
    r the difference with the yaw wrapped, S the sum of the two covariances."""
    r = np.asarray(pose, dtype=np.float64).reshape(3) - np.asarray(pred_pose, dtype=np.float64).reshape(3)
    r[2] = math.atan2(math.sin(r[2]), math.cos(r[2]))
    s = np.asarray(cov, dtype=np.float64).reshape(3, 3) + np.asarray(pred_cov, dtype=np.float64).reshape(3, 3)
    s = 0.5 * (s + s.T)
    sign, logdet = np.linalg.slogdet(s)
    if sign <= 0:
        return -math.inf
    return float(-0.5 * (r @ np.linalg.solve(s, r) + logdet))


def choose_hypothesis(pose, cov, predictions, min_evidence: float = MIN_EVIDENCE) -> tuple[int | None, float]:
    """(index of the likeliest prediction, its log-likelihood lead over the next) for a matched pose
    (float[3], cov float[3, 3]) among ``predictions`` [(pose, cov), …]; the index None (undecided)
    where the lead is under ``min_evidence`` nats."""
    ll = [log_likelihood(pose, cov, *p) for p in predictions]
    best = int(np.argmax(ll))
    lead = float(ll[best] - max((v for j, v in enumerate(ll) if j != best), default=-math.inf))
    return (best if lead >= float(min_evidence) else None), lead


def decide_time(options_us, ref_us: int, step, lead_s: float, readings_around, agree,
                gate_d2: float = DECISION_D2) -> tuple[int | None, float]:
    """(index into ``options_us`` of the sweep's time or None where undecided, the evidence in nats)
    by the match: the readings of the new sweep from windows centred around each reading's prediction,
    pooled; the largest group of them that agree (`radar_odom.odometry.gaps.consensus`: one window's
    reading alone can be a wrong peak, sharper than the right one) is the motion, and
    `choose_hypothesis` picks the prediction that explains it.

    Args:
        options_us: the sweep's candidate times (µs), the fit's first (`SweepTimes.options`).
        ref_us: the reference sweep's time (µs).
        step: (pose float[3], cov float[3, 3], seconds) the motion prior's last velocity as a step
            over its interval (`radar_odom.odometry.motion_prior.MotionPrior`).
        lead_s: seconds from the end of that step to ``ref_us``.
        readings_around: ``pose -> [(pose, cov), …]``: the new sweep matched with the search window
            centred around ``pose`` (the vehicle's frame, relative to the reference;
            `radar_odom.odometry.gaps.crossing_readings`), each reading composed back.
        agree: (m, rad, m) `radar_odom.odometry.gaps.agreement` of the model.
        gate_d2: a motion that the likeliest reading's prediction puts beyond this d²
            (`radar_odom.odometry.gaps.crossing_d2`) decides nothing (`DECISION_D2`).

    Returns None for the index where no two readings agree (evidence 0.0), where no reading leads,
    or where the likeliest reading's prediction rules the agreed motion out.
    """
    predictions = [crossing_prior(step[0], step[1], step[2], (t - ref_us) * 1e-6, lead_s) for t in options_us]
    pooled = [r for p in predictions for r in readings_around(p[0])]
    tol_m, tol_rad, sharp_m = agree
    agreed = consensus([r[0] for r in pooled], [r[1] for r in pooled], tol_m, tol_rad, sharp_m)
    if agreed is None:
        return None, 0.0
    chosen, lead = choose_hypothesis(agreed[0], agreed[1], predictions)
    if chosen is not None and crossing_d2(agreed[0], agreed[1], *predictions[chosen]) > float(gate_d2):
        return None, lead  # a motion that its likeliest reading's prediction rules out too
    return chosen, lead


def rotation_period_s(scan: RadarScan) -> float | None:
    """One turn of the sensor (s) from the sweep's own azimuth times: the median over consecutive rows
    of Δt / Δθ, times 2π; None where the rows share one time (a format without per-azimuth times)."""
    t = np.asarray(scan.timestamps_us, dtype=np.float64)
    a = np.unwrap(np.asarray(scan.azimuths_rad, dtype=np.float64))
    dt, da = np.diff(t), np.diff(a)
    ok = (dt > 0) & (da > 0)
    if ok.sum() < max(3, t.size // 4):
        return None
    return float(np.median(dt[ok] / da[ok]) * 2.0 * math.pi * 1e-6)


class SweepTimes:
    """The odometer's view of a recording's `TimeBase`: which sweeps the stamps cannot place, and
    the times the match decided for them. ``None``: no time base, every sweep at its own time."""

    def __init__(self, time_base: TimeBase | None):
        if time_base is not None and not isinstance(time_base, TimeBase):
            raise ConfigError(f"time_base must be a radar_odom.io.timebase.TimeBase (Sequence.time_base) or None, "
                              f"got {type(time_base).__name__}")
        self._base = time_base
        self.reset()

    def reset(self) -> None:
        """Forget the decisions (a new stream)."""
        self._choices: dict[int, int] = {}
        self._rotation_checked = False

    @property
    def time_base(self) -> TimeBase | None:
        """The recording's time base with the match's decisions taken (`TimeBase.decided`), or None."""
        return None if self._base is None else self._base.decided(self._choices)

    @property
    def period_s(self) -> float | None:
        return None if self._base is None else self._base.period_s

    def index(self, ts_us: int) -> int | None:
        """The sweep of the time base with this time (its fitted time or its stamp, within a quarter
        period: sweeps lie a period apart), or None."""
        base = self._base
        if base is None or base.times_us.size == 0:
            return None
        for times in (base.times_us, base.stamps_us):
            j = int(np.clip(np.searchsorted(times, ts_us), 1, times.size - 1)) if times.size > 1 else 0
            near = min((j - 1, j) if times.size > 1 else (0,), key=lambda m: abs(int(times[m]) - int(ts_us)))
            if abs(int(times[near]) - int(ts_us)) <= max(0.25 * base.period_us, 1.0):
                return near
        return None

    def options(self, ts_us: int, last_us: int) -> list[tuple[int, int]]:
        """[(k, time µs), …] the readings of the sweep at ``ts_us`` that may follow the stream's last
        sweep (``last_us``, as decided): later than it by at least half a period; the fit's first."""
        i = self.index(ts_us)
        if i is None:
            return []
        base = self._base
        half = 0.5 * base.period_us
        return [(k, base.time_at(i, k)) for k in base.candidates(i) if base.time_at(i, k) - int(last_us) >= half]

    def decide(self, ts_us: int, k: int) -> int:
        """Take reading ``k`` for the sweep at ``ts_us``; returns its time (µs)."""
        i = self.index(ts_us)
        self._choices[i] = int(k)
        return self._base.time_at(i, k)

    def adopt_rotation(self, scan: RadarScan) -> bool:
        """Once per stream: where the stamps alone chose the period among its whole fractions, refit
        the time base with the sweep's own rotation time as the period hint (`rotation_period_s`);
        True where that changed the period. The times stay (the same either way), the indices follow."""
        if self._rotation_checked or self._base is None or self._base.period_from != "stamps":
            return False
        self._rotation_checked = True
        rotation = rotation_period_s(scan)
        cands = self._base.candidate_periods_us
        if rotation is None or len(cands) < 2:
            return False
        best = min(cands, key=lambda p: abs(p - rotation * 1e6))
        if best == cands[0] or abs(best - rotation * 1e6) > ROTATION_TOLERANCE * best:
            return False
        refit = fit_time_base(self._base.stamps_us, period_hint_us=rotation * 1e6)
        self._base = replace(refit, period_from=f"the sweep's own turn ({rotation * 1e3:.0f} ms) picked it among "
                                                "the whole fractions")
        return True
