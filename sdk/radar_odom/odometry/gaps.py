"""Crossing a gap in a recording: dropped sweeps, a stalled driver, a bridged degenerate sweep.

Over a gap the car moves further than the graph's search window reaches (RADIATE drives hold
holes of 1.3–1.5 s, 10–16 m at city speed, against a ±8 m window), so a plain match clips
to the window's edge or locks onto a wrong peak. The odometer instead draws the new sweep in the
frame the motion prior predicts for it (`radar_odom.odometry.sweep_input.SweepMotion.frame_pose` =
P⁻¹), so the graph measures only the residual M of the prediction P, and composes the two:
the new sweep's pose in the reference frame is ``M ∘ P``, whose covariance is the residual's
carried through that composition (P is not uncertain there: it only placed the window).

`SweepPeriod` tells a gap from an ordinary step: the sensor's period where known (a recording's
fitted time base, `radar_odom.io.timebase`), else the median of the recent intervals, is the
nominal period, and an interval beyond ``gap_factor`` × that is a gap. The median alone fails
where a recording drops every other sweep for a while: its intervals all read two periods.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

GAP = "gap"  # flag of an estimate whose interval was a gap (see `SweepPeriod`)
NEW_SEGMENT = "new_segment"  # flag of the first sweep after a stamp jump no prediction can bridge
# Beyond this a constant-velocity prediction cannot place the ±8 m search window: its 4 m/s² spread
# alone is ½·a·t² = 200 m at 10 s (a one-hour stamp jump was extrapolated into a 24 km step). The
# stream starts a new segment there: the sweep is kept at the last pose, unrelated to it.
NEW_SEGMENT_GAP_S = 10.0
GAP_FACTOR = 1.5  # an interval above 1.5 nominal periods: at least one sweep is missing
_MIN_INTERVALS = 3  # intervals seen before the period is trusted


class SweepPeriod:
    """The nominal interval between sweeps of a stream: ``known_s`` (the sensor's period, s) where
    given, else the median of the last ``window`` ones."""

    def __init__(self, window: int = 15, gap_factor: float = GAP_FACTOR, known_s: float | None = None):
        self._dts: deque = deque(maxlen=int(window))
        self.gap_factor = float(gap_factor)
        self.known_s = None if known_s is None else float(known_s)

    def reset(self) -> None:
        self._dts.clear()

    @property
    def nominal_s(self) -> float | None:
        """The known period (s), else the median interval, or None before three intervals are known."""
        if self.known_s is not None:
            return self.known_s
        if len(self._dts) < _MIN_INTERVALS:
            return None
        return float(np.median(np.asarray(self._dts)))

    def is_gap(self, interval_s: float) -> bool:
        """Whether ``interval_s`` is longer than ``gap_factor`` nominal periods (False while the
        period is unknown)."""
        nominal = self.nominal_s
        return nominal is not None and float(interval_s) > self.gap_factor * nominal

    def observe(self, dt_s: float) -> None:
        """Record one interval between consecutive sweeps (s)."""
        self._dts.append(float(dt_s))


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
