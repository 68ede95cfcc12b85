"""What the odometer hands out and takes in: `Estimate` (one step), `Trajectory` (the stream's
absolute poses), `PreparedSweep` (a sweep made ready ahead of `RadarOdometer.step`), and the
covariance of knowing nothing (`window_covariance`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scan import RadarScan
from .motion_prior import GATED, PRIOR_DOMINATED

DEGENERATE = "degenerate"  # flag of a prior-only estimate (the sweep could not be matched)
BRIDGED = "bridged"  # flag of a match against an older sweep, across degenerate ones


@dataclass(frozen=True)
class PreparedSweep:
    """A sweep made ready for `RadarOdometer.step` by `RadarOdometer.prepare`.

    The per-sweep work that does not depend on the stream (the degeneracy test and the graph
    input, e.g. the polar-to-Cartesian resampling) done ahead, possibly on another thread, so
    that `step` only runs the graph. ``problem``: `sweep_problem`'s verdict; ``input``: the
    graph input, or None when the sweep is degenerate or the model cannot take it (then `step`
    raises `ModelMismatchError` in its turn, as for the bare scan).
    """

    scan: RadarScan
    problem: str | None
    input: np.ndarray | None
    ready: bool = field(default=False, repr=False)  # False: step() works from the scan alone
    owner: object = field(default=None, repr=False, compare=False)  # the odometer that prepared it


@dataclass(frozen=True)
class Estimate:
    """One odometry step.

    Attributes:
        pose: float64[3] (x m, y m, yaw rad): the new sweep's frame in the previous sweep's frame
            (the vehicle's frames where the model carries a mount yaw, ``radar-odom adapt``).
        covariance: float64[3, 3] over (x, y, yaw), symmetric.
        timestamp_us: the new sweep's timestamp (first azimuth, the Oxford file name).
        flags: empty for a normal match; ``{"degenerate", reason}`` for a prior-only estimate
            (reason: ``invalid_rows``, ``partial_coverage``, ``saturated``, ``blank``,
            ``noise_only`` (see `sweep_problem`), ``nonfinite``, ``no_reference``, or the
            reason given to `RadarOdometer.skip`, e.g. ``unreadable``),
            ``{"bridged"}`` when matched against an older sweep across a degenerate one;
            with the motion prior also ``"prior_dominated"`` (the motion comes mostly from the
            prior), ``"gated"`` (the match was implausible and left out: the pose is the
            prior's) and ``"prior_reset"`` (a match failing the gate taken as it is, after
            consecutive gated steps). A degenerate estimate is prior-only by definition and
            carries no ``"prior_dominated"``.
        measurement: float64[3] the match as the graph gave it (re-expressed against the
            previous sweep like ``pose`` when bridged), before the motion prior; for a
            degenerate sweep the prior-only pose. Defaults to ``pose``.
        measurement_covariance: float64[3, 3] its covariance. Defaults to ``covariance``.
    """

    pose: np.ndarray
    covariance: np.ndarray
    timestamp_us: int
    flags: frozenset = field(default_factory=frozenset)
    measurement: np.ndarray | None = None
    measurement_covariance: np.ndarray | None = None

    def __post_init__(self):
        if self.measurement is None:
            object.__setattr__(self, "measurement", np.array(self.pose, dtype=np.float64))
        if self.measurement_covariance is None:
            object.__setattr__(self, "measurement_covariance", np.array(self.covariance, dtype=np.float64))

    @property
    def degenerate(self) -> bool:
        return DEGENERATE in self.flags

    @property
    def prior_dominated(self) -> bool:
        return PRIOR_DOMINATED in self.flags

    @property
    def gated(self) -> bool:
        return GATED in self.flags


@dataclass(frozen=True)
class Trajectory:
    """Absolute poses of every sweep of the current stream (first = identity)."""

    poses: np.ndarray  # float64[N, 3, 3]
    timestamps_us: np.ndarray  # int64[N]

    def __len__(self) -> int:
        return len(self.timestamps_us)


def window_covariance(profile) -> np.ndarray:
    """float64[3, 3]: covariance of a uniform pose over the search window (knows nothing)."""
    a = profile.translation_cells * profile.resolution_m
    r = round(profile.rotation_range_rad / profile.rotation_step_rad) * profile.rotation_step_rad
    return np.diag([a * a / 3.0, a * a / 3.0, r * r / 3.0])
