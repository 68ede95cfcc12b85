"""A stream's state, held once: `StreamState` (the trajectory, where each sweep sits on the sensor's period
count, the velocity's end, the last second's yaw rates) and its `Reference` (the sweep new ones are matched
against). `RadarOdometer` keeps one of each per stream; the stages read and move them."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from ..scan import RadarScan

RECENT_PERIODS = 4  # the last second of steps (4 Hz): the yaw rates a gap crossing must be drivable from


@dataclass
class Reference:
    """The sweep new ones are matched against: the graph's state of it (``feed``), its place in the trajectory
    (``index``), the sweep as recorded (``scan``: a gap crossing and de-skew redraw it), and the turn (rad;
    `radar_odom.odometry.centring`) and de-skew twist it was drawn with."""

    feed: np.ndarray | None = None
    index: int = -1
    scan: RadarScan | None = None
    turn: float = 0.0
    twist: tuple | None = None


class StreamState:
    """One stream: the absolute poses, stamps and period ticks of its sweeps (``ticks[i]``: the sensor
    periods from the stream's first sweep to sweep i, as the match decided them), the `Reference`, the tick
    where the velocity's interval ends, external odometry since the reference ((pose, cov), None if unknown),
    the yaw rates (rad/s) of the last `RECENT_PERIODS` accepted steps, the stream's range bins and azimuth count."""

    def __init__(self):
        self.poses: list[np.ndarray] = []
        self.stamps: list[int] = []
        self.ticks: list[int] = []
        self.ref = Reference()
        self.velocity_end_tick: int | None = None
        self.odometry_since_ref: tuple | None = None
        self.yaw_rates: deque = deque(maxlen=RECENT_PERIODS)
        self.range_scale: tuple | None = None
        self.azimuths: int | None = None

    def forget_motion(self) -> None:
        """A new segment: how the stream moved is unknown from here."""
        self.velocity_end_tick = None
        self.odometry_since_ref = None
        self.yaw_rates.clear()

    def append(self, absolute: np.ndarray, ts: int, periods: int) -> None:
        """The next sweep at ``absolute`` (float64[3, 3]), stamped ``ts`` µs, ``periods`` after the last."""
        self.poses.append(absolute)
        self.stamps.append(int(ts))
        self.ticks.append(self.ticks[-1] + int(periods) if self.ticks else 0)

    def periods_since(self, index: int) -> int:
        """Sensor periods from sweep ``index`` to the last sweep."""
        return self.ticks[-1] - self.ticks[index]
