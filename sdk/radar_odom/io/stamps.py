"""Late sweep stamps: a spinning radar's sweeps come at its fixed period; some recordings stamp them late.

RADIATE stamps each sweep on the recording computer. On the shared city drive
(`radiate-2019-02-12-edinburgh`) three stamps are 0.22–0.27 s late — an interval of ≈ 0.5 s with
consecutive frame numbers — and the stamps that follow come every ≈ 0.23 s until they are back on
the sensor's 0.25 s rhythm, 12–14 sweeps later. No sweep is missing there: every matcher measures
one period of motion across those "gaps". A reference sampled at such stamps is wrong for every
sweep of the catch-up (its steps 8 % short, then one step twice as long), which on the drive's last
80 sweeps made every matcher's yaw read 0.89 of the reference's.

`repair_late_stamps` puts late stamps back: the sensor's period P is the median interval between
stamps (a dropped sweep or a late stamp is one interval of many; the catch-ups' short intervals can
only pull it low, which is the safe side, see below), and since a stamp can be late
but never early, sweep i cannot have happened after any later sweep j's stamp less (j − i) periods:
``T_i = min_{i ≤ j ≤ i + lookahead} (t_j − P·(j − i))``. Only later stamps bound a sweep: a sweep
really missing between i and j makes that bound one period looser, never wrong, so a dropped sweep
keeps its gap. Stamps less late than `MIN_LATE_PERIODS` of a period (the ordinary jitter of a host
stamp) are left alone unless they end a late run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SequenceError

LOOKAHEAD_SWEEPS = 24  # a catch-up of the shared drive takes 12–14 sweeps
# A period too long would move every stamp early by up to lookahead × the excess; one too short only
# leaves lookahead × the shortfall of a late stamp uncorrected (the shared drive's median interval is
# 0.65 ms short of its stamps' long-run slope: ≤ 9 ms left over its 14-sweep catch-ups).
# A late run starts at a stamp more than a tenth of a period late (less is a host's ordinary jitter,
# left alone) and goes on while the stamps are still late by more than 2 % of a period (the tail of
# the catch-up: without it the run would stop 25 ms short of the sensor's rhythm).
MIN_LATE_PERIODS = 0.1
RUN_END_LATE_PERIODS = 0.02
MIN_SWEEPS = 4  # fewer stamps cannot tell a late stamp from a slow sensor


@dataclass(frozen=True)
class StampRepair:
    """Stamps put back on the sensor's period (`repair_late_stamps`).

    Attributes:
        timestamps_us: int64[N] the repaired stamps (unchanged where not late).
        corrections_us: int64[N] how late each stamp was (``stamp − repaired``, ≥ 0; 0 where unchanged).
        period_us: the sensor period used (µs; 0.0 where too few stamps to tell).
    """

    timestamps_us: np.ndarray
    corrections_us: np.ndarray
    period_us: float

    @property
    def late(self) -> np.ndarray:
        """int64[K] indices of the stamps that were moved."""
        return np.flatnonzero(self.corrections_us > 0)

    def summary(self) -> str:
        """One line for a run's notes: how many stamps were late and by how much (empty if none)."""
        late = self.late
        if late.size == 0:
            return ""
        jumps = int(np.sum(np.diff(np.concatenate([[-2], late])) > 1))
        return (f"{late.size} sweep stamps were late (up to {self.corrections_us.max() / 1e3:.0f} ms, in {jumps} "
                f"run{'s' if jumps != 1 else ''}; sensor period {self.period_us / 1e3:.2f} ms) and were put back "
                "on the sensor's period")


def repair_late_stamps(timestamps_us, lookahead: int = LOOKAHEAD_SWEEPS) -> StampRepair:
    """Late sweep stamps put back on the sensor's period (module docstring).

    Args:
        timestamps_us: int[N] sweep stamps (µs), strictly increasing.
        lookahead: how many later stamps may bound a sweep's time.

    Returns:
        `StampRepair`; stamps unchanged (corrections 0) where fewer than `MIN_SWEEPS`.

    Raises:
        SequenceError: stamps that do not increase.
    """
    t = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    intervals = np.diff(t)
    if not np.all(intervals > 0):
        raise SequenceError("sweep stamps must increase strictly; sort the sweeps by time or drop the duplicates")
    if t.size < MIN_SWEEPS:
        return StampRepair(t.copy(), np.zeros_like(t), 0.0)
    # the median interval: a host's jitter cancels in it (two equally late stamps), a few dropped sweeps
    # or late stamps do not move it
    period = float(np.median(intervals))
    tf = t.astype(np.float64)
    bound = tf.copy()
    for k in range(1, int(max(0, lookahead)) + 1):
        # sweep i is at most t[i + k] − k·P
        np.minimum(bound[:-k], tf[k:] - k * period, out=bound[:-k])
    late_us = tf - bound
    moved = late_us > MIN_LATE_PERIODS * period
    for i in range(1, t.size):  # carry each run through its tail
        moved[i] |= moved[i - 1] and late_us[i] > RUN_END_LATE_PERIODS * period
    corrections = np.where(moved, np.round(late_us), 0.0).astype(np.int64)
    return StampRepair(t - corrections, corrections, float(period))
