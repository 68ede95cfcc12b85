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
