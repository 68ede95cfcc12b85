"""Simulated sweeps stamped the way a recording host stamps them: some dropped, some late, jittered.

The simulator times every sweep exactly (``RadarScan.timestamp_us`` is its first azimuth's time).
A RADIATE or ROS recording host stamps a sweep when it receives it: late now and then, with a few ms
of jitter, and never stamps the sweeps it dropped. These two pure functions make such a recording from
a simulated drive, with the truth still known, to test a reader's time base
(`radar_odom.io.timebase`) and what the odometry makes of it (`radar_odom.odometry.match_stage`: the match decides).
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np


def host_stamps(true_us, keep, late_us=None, jitter_us: float = 0.0, seed: int = 0) -> np.ndarray:
    """int64[K] the stamps a host writes for the sweeps ``keep`` (indices into ``true_us``, increasing).

    Args:
        true_us: int[N] the sweeps' true first-azimuth times (µs).
        keep: the sweeps the host received (the others were dropped).
        late_us: {sweep index: delay µs} stamps late by that much (≥ 0); None: none.
        jitter_us: each stamp moved by a uniform draw in ±``jitter_us``.
        seed: the jitter's random generator.
    """
    keep = np.asarray(keep, dtype=np.int64)
    t = np.asarray(true_us, dtype=np.float64)[keep]
    for i, delay in (late_us or {}).items():
        t[np.flatnonzero(keep == int(i))] += float(delay)
    t += np.random.default_rng(seed).uniform(-jitter_us, jitter_us, t.size)
    return np.round(t).astype(np.int64)


def timed(scans, times_us) -> list:
    """The scans moved onto ``times_us`` (µs, one per scan): every azimuth's time shifted by the same
    amount, as a reader shifts a sweep it re-times (`radar_odom.io.sequence.Sequence.scan`)."""
    return [replace(s, timestamps_us=s.timestamps_us - s.timestamp_us + int(t)) for s, t in zip(scans, times_us)]
