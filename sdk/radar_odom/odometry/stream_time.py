"""The time stage of a step: may this sweep follow the stream, and over what interval?

Pure checks; the odometer keeps the stream's stamps and acts on the verdicts (a gap's flag and
crossing: `radar_odom.odometry.gaps`; the recording's period: ``RadarOdometer(sweep_period_s=)``,
fitted once per recording by `radar_odom.io.timebase`).
"""
from __future__ import annotations

import numpy as np

from ..errors import StreamError
from ..scan import RadarScan


def interval_s(ts_us: int, last_us: int, source: str) -> float:
    """Seconds from the stream's last sweep (``last_us``) to ``ts_us``; `StreamError` unless it is > 0."""
    dt_s = (int(ts_us) - int(last_us)) * 1e-6
    if dt_s <= 0:
        raise StreamError(
            f"{source}: timestamp {ts_us} µs does not increase (previous sweep {last_us} µs); "
            "sweeps must come in time order — call reset() to start a new stream"
        )
    return dt_s


def beyond_max_gap(source: str, dt_s: float, max_gap_s: float) -> StreamError:
    """The error of an interval longer than the odometer's ``max_gap_s`` (with ``on_gap="raise"``)."""
    return StreamError(
        f"{source}: {dt_s:.3f} s since the previous sweep exceeds max_gap_s={max_gap_s} s; "
        "odometry cannot bridge it — call reset() to start a new stream (or use on_gap='reset')"
    )


def range_bins(scan: RadarScan, stream_bins: tuple | None) -> tuple[float, float]:
    """(range resolution m, range offset m) of ``scan``; `StreamError` where they differ from the
    stream's (``stream_bins``; None: a new stream). A radar does not change them mid-recording, so the
    reader's settings are wrong, and matching across the change would read a scale error as motion."""
    bins = (float(scan.range_resolution_m), float(scan.range_offset_m))
    if stream_bins is not None and not np.allclose(bins, stream_bins, rtol=1e-6, atol=1e-9):
        raise StreamError(
            f"{scan.source}: range bins of {bins[0]} m from {bins[1]} m, but this stream's are "
            f"{stream_bins[0]} m from {stream_bins[1]} m; a radar does not change them mid-recording "
            "— check the reader's range resolution, or call reset() to start a new stream")
    return bins


AZIMUTH_COUNT = "azimuth_count"  # the degenerate reason of a sweep whose azimuth count is not the stream's
MAX_AZIMUTH_COUNT_CHANGE = 0.05  # a few rows more or fewer (a dropped packet) are matched as they are


def azimuth_count(scan: RadarScan, stream_azimuths: int | None) -> tuple[int, str | None]:
    """(the stream's azimuth count, `AZIMUTH_COUNT` where ``scan``'s differs from it by more than
    `MAX_AZIMUTH_COUNT_CHANGE`, else None). ``stream_azimuths``: the count of the stream's first sweep (None: a new
    stream, which takes ``scan``'s). A radar turns out the same rows every sweep; a sweep with half of them (a
    reader or driver cutting it short) spread over the whole turn matches a full one confidently and wrongly
    (issue 42 reports −0.73 m for a 2.2 m step), so it is flagged degenerate rather than matched."""
    count = int(scan.num_azimuths)
    if stream_azimuths is None:
        return count, None
    if abs(count - int(stream_azimuths)) > MAX_AZIMUTH_COUNT_CHANGE * int(stream_azimuths):
        return int(stream_azimuths), AZIMUTH_COUNT
    return int(stream_azimuths), None


# an interval is read as whole periods by rounding; below this many one-period intervals the median is not
# trusted and every interval counts as one period
MIN_PERIOD_INTERVALS = 3
# a sweep whose azimuth times span a turn of this long at least (s) tells the sensor's period itself
MIN_ROTATION_S = 0.05
# A stream's first step has no velocity for the match to agree with, so the stamps alone count its periods:
# there they must say 1.75 periods, not 1.5, before a sweep is called dropped (a host's first stamp 143 ms
# late made a phantom gap on a fresh junction drive, benchmarks/do_no_harm.py, seed 2055022335)
FIRST_STEP_MARGIN = 0.25


class StreamClock:
    """How many of the sensor's periods the stamps put between sweeps.

    The period is ``known_s`` (the sensor's, given), else the rotation time of the stream's first sweep where
    its azimuth times span a turn (Oxford, Boreas, the simulator), else the median of the last ``window``
    intervals the odometer took as one period (a host's catch-up at 0.9 of the period moves it, and it follows;
    a stall's long interval is two periods and stays out). Stamps only advise: the match decides how many
    periods a step spans (`radar_odom.odometry.match_stage`), and `observe` hears its verdict.
    """

    def __init__(self, known_s: float | None = None, window: int = 15):
        from collections import deque

        self.known_s = None if known_s is None else float(known_s)
        self._rotation_s: float | None = None
        self._one_period: deque = deque(maxlen=int(window))

    def reset(self) -> None:
        self._rotation_s = None
        self._one_period.clear()

    def adopt_rotation(self, scan: RadarScan) -> None:
        """The stream's first sweep: its own rotation time, where its azimuth times span a turn."""
        t = np.asarray(scan.timestamps_us, dtype=np.float64)
        a = int(t.size)
        if a >= 2 and self._rotation_s is None:
            span = (t.max() - t.min()) * 1e-6 * a / (a - 1)
            self._rotation_s = span if span >= MIN_ROTATION_S else None

    @property
    def period_s(self) -> float | None:
        """The period (s) stamps are read in, or None while unknown."""
        if self.known_s is not None:
            return self.known_s
        if self._rotation_s is not None:
            return self._rotation_s
        if len(self._one_period) < MIN_PERIOD_INTERVALS:
            return None
        return float(np.median(np.asarray(self._one_period)))

    def periods(self, interval_s: float, margin: float = 0.0) -> int:
        """The whole periods (≥ 1) the stamps put in ``interval_s`` (1 while the period is unknown), rounded
        after taking ``margin`` periods off (a step no match can judge: the stream's first)."""
        p = self.period_s
        return 1 if p is None else max(1, int(round(float(interval_s) / p - float(margin))))

    def observe(self, interval_s: float, periods: int) -> None:
        """A step's stamp interval and the periods the odometer took it to span."""
        if int(periods) == 1:
            self._one_period.append(float(interval_s))
