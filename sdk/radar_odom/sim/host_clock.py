"""Simulated recording hosts whose clocks misbehave the way real ones do (issue 50, item 1).

A RADIATE or ROS recording host stamps each sweep when it receives it. `host_stamps.host_stamps`
makes such stamps from a list of late sweeps and a jitter; a `HostClock` draws that list (and more)
from a model of one host, so that a whole simulated drive can be stamped like a real recording:

* **jitter**: every stamp moved by a *uniform* draw in ±``jitter_us`` (`host_stamps.host_stamps`).
  Uniform, not Gaussian: on the shared RADIATE drive the on-time intervals span 239–263 ms around
  250 ms with a standard deviation of 4.9 ms and an excess kurtosis of −0.4, the triangle that the
  difference of two ±6 ms uniform draws gives (σ 4.9 ms, range ±12 ms; a Gaussian of that σ reaches
  ±14 ms in 231 intervals).
* **stalls** (``stall_rate`` per sweep, drawn only once the previous stall's backlog is drained): the
  host stops stamping for a while, so one interval is long; its backlog then arrives either in a
  **catch-up** run, each interval ``catch_up_ratio`` (about 0.9) of the period until the stamps are back
  on time (the run lasts ``catch_up_sweeps``, 10–150, drawn from a Pareto tail), or, for a share
  ``burst_share`` of the stalls, in a **burst** of intervals ``burst_spacing_periods`` of a period
  apart, which the jitter turns negative now and then. A stall's size is the run's length times
  what each catch-up interval gains: ``L · (1 − ratio) · P``.
* **backwards stamps** (``backwards_rate`` per sweep): one stamp late by ``backwards_late_periods``
  periods while the next is on time, so one long interval is followed by a negative one (another
  RADIATE drive's 857/−401 and 1023/−572 ms pairs).
* **duplicated stamps** (``duplicate_rate`` per sweep): the host writes the previous stamp again.
* **true drops** (``drop_rate`` events per sweep, each of 1–8 sweeps with the weights
  ``drop_lengths``): those sweeps never reach the host and get no stamp. With the drive's yaw rate
  (``turn_rate_rps``), a share ``drop_turn_share`` of the events is placed at sweeps where
  |yaw rate| ≥ ``turn_rate_threshold_rps`` (inside junction turns), where a drop hurts most.

The sweep 0 is never dropped (a recording starts with a sweep), and a drop event that would touch an
earlier one is left out (each gap is one event's length). Stamps are never earlier than the
truth except by the jitter or a repeated stamp (hosts stamp on reception: late, never early); a host's constant latency
is not modelled (nothing in the stamps can show it).

`PRESETS`: ``perfect`` (the true stamps, nothing dropped), ``clean`` (a sensor's own stamps, as
Oxford's and bags stamped by the sensor: ±0.5 ms, rare drops, nothing else) and ``radiate`` (fitted
to the shared RADIATE drive's stamps; see docs/time-base.md, "Simulated host clocks", and
``benchmarks/host_clock_fit.py``). `interval_stats` gives the statistics that fit compares.

Pure functions and frozen dataclasses, numpy only; the same clock, true times and seed always give
the same `ClockedSweeps`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ..errors import ConfigError
from .host_stamps import host_stamps

MAX_DROP_LENGTH = 8  # sweeps: a longer loss is an outage, not a drop


@dataclass(frozen=True)
class ClockedSweeps:
    """What a host made of a sweep train.

    Attributes:
        keep: int64[K] indices (into the true times) of the sweeps the host received, increasing
            (the order the host received and wrote them in).
        stamps_us: int64[K] the stamps the host wrote for them (µs): jittered, stalled, repeated or
            going backwards as the clock says.
        dropped: int64[N − K] indices of the sweeps really dropped, increasing.
    """

    keep: np.ndarray
    stamps_us: np.ndarray
    dropped: np.ndarray


def _range(value, name: str, low: float = 0.0, high: float = math.inf) -> None:
    lo, hi = value
    if not (math.isfinite(lo) and math.isfinite(hi) and low <= lo <= hi <= high):
        raise ConfigError(f"HostClock.{name} must be (low, high) with {low:g} ≤ low ≤ high ≤ {high:g}, got {value!r}")


@dataclass(frozen=True)
class HostClock:
    """A model of how a recording host stamps the sweeps of a sensor with period P (µs).

    Attributes:
        name: the preset's name (or yours).
        jitter_us: each stamp moved by a uniform draw in ±``jitter_us``.
        stall_rate: stalls per sweep (a stall starts only once the previous one's backlog is drained):
            one long interval, then the backlog arrives in a catch-up run or a burst.
        catch_up_ratio: (low, high) of a catch-up run's intervals, in periods (drawn per stall).
        catch_up_sweeps: (shortest, longest) catch-up run, sweeps.
        catch_up_tail: Pareto index of a run's length L = shortest · U^(−1/tail), cut at the longest
            (median shortest · 2^(1/tail)).
        burst_share: share of the stalls whose backlog arrives in a burst instead of a catch-up run.
        burst_spacing_periods: (low, high) of the intervals within a burst, in periods.
        duplicate_rate: per sweep: the host writes the previous stamp again.
        backwards_rate: per sweep: the stamp is late by ``backwards_late_periods`` periods, the next one
            on time (a long interval, then a negative one).
        backwards_late_periods: (low, high), periods; above 1 so the next interval goes back.
        drop_rate: drop events per sweep.
        drop_lengths: weights of a drop of 1, 2, … sweeps (at most `MAX_DROP_LENGTH` entries).
        drop_turn_share: with ``turn_rate_rps``, the share of drop events moved into turns.
        turn_rate_threshold_rps: |yaw rate| (rad/s) from which a sweep counts as inside a turn.
    """

    name: str
    jitter_us: float = 0.0
    stall_rate: float = 0.0
    catch_up_ratio: tuple[float, float] = (0.90, 0.95)
    catch_up_sweeps: tuple[int, int] = (10, 150)
    catch_up_tail: float = 3.0
    burst_share: float = 0.0
    burst_spacing_periods: tuple[float, float] = (0.0, 0.05)
    duplicate_rate: float = 0.0
    backwards_rate: float = 0.0
    backwards_late_periods: tuple[float, float] = (1.5, 3.5)
    drop_rate: float = 0.0
    drop_lengths: tuple[float, ...] = (1.0,)
    drop_turn_share: float = 0.5
    turn_rate_threshold_rps: float = 0.15

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "name":
                if not isinstance(v, str) or not v:
                    raise ConfigError(f"HostClock.name must be a non-empty string, got {v!r}")
            elif isinstance(v, tuple):
                if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v):
                    raise ConfigError(f"HostClock.{f.name} must hold finite numbers, got {v!r}")
            elif isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"HostClock.{f.name} must be a finite number ≥ 0, got {v!r}")
        for rate in ("stall_rate", "burst_share", "duplicate_rate", "backwards_rate", "drop_rate", "drop_turn_share"):
            if getattr(self, rate) > 1:
                raise ConfigError(f"HostClock.{rate} must be within 0..1, got {getattr(self, rate)!r}")
        _range(self.catch_up_ratio, "catch_up_ratio", 0.0, 1.0)
        if self.catch_up_ratio[1] >= 1.0:
            raise ConfigError(f"HostClock.catch_up_ratio must stay below 1 (a run that gains nothing never ends), "
                              f"got {self.catch_up_ratio!r}")
        _range(self.catch_up_sweeps, "catch_up_sweeps", 1.0)
        _range(self.burst_spacing_periods, "burst_spacing_periods", 0.0, 1.0)
        _range(self.backwards_late_periods, "backwards_late_periods", 0.0)
        if self.catch_up_tail <= 0:
            raise ConfigError(f"HostClock.catch_up_tail must be > 0, got {self.catch_up_tail!r}")
        w = self.drop_lengths
        if not 1 <= len(w) <= MAX_DROP_LENGTH or min(w) < 0 or sum(w) <= 0:
            raise ConfigError(f"HostClock.drop_lengths must be 1–{MAX_DROP_LENGTH} weights ≥ 0 (of drops of 1, 2, … "
                              f"sweeps), not all 0, got {w!r}")

    @property
    def is_perfect(self) -> bool:
        """Whether the clock leaves every sweep and its true stamp as it is."""
        return not (self.jitter_us or self.stall_rate or self.duplicate_rate or self.backwards_rate or self.drop_rate)

    def apply(self, true_us, seed: int, turn_rate_rps=None) -> ClockedSweeps:
        """The sweeps this host receives of a train whose first azimuths are at ``true_us``, and their stamps.

        Args:
            true_us: int[N] the sweeps' true times (µs), strictly increasing; the period P is the median
                interval.
            seed: the random draws (the same seed gives the same result).
            turn_rate_rps: float[N] the drive's yaw rate at each sweep (rad/s), or None: drops placed
                uniformly.

        Raises:
            ConfigError: ``true_us`` not strictly increasing integers, ``turn_rate_rps`` of another length or
                not finite, a seed that is not an integer ≥ 0.
        """
        true = np.asarray(true_us)
        if true.ndim != 1 or (true.size and not np.issubdtype(true.dtype, np.integer)
                              and not np.all(np.asarray(true, dtype=np.float64) == np.round(true))):
            raise ConfigError(f"true_us must be a 1-D array of integer µs, got shape {true.shape} {true.dtype}")
        true = true.astype(np.int64)
        n = true.size
        if n > 1 and np.any(np.diff(true) <= 0):
            raise ConfigError("true_us must be strictly increasing (the sweeps' true first-azimuth times)")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ConfigError(f"seed must be an integer ≥ 0, got {seed!r}")
        rates = None
        if turn_rate_rps is not None:
            rates = np.asarray(turn_rate_rps, dtype=np.float64)
            if rates.shape != (n,) or not np.all(np.isfinite(rates)):
                raise ConfigError(f"turn_rate_rps must be {n} finite yaw rates (rad/s, one per sweep), got shape "
                                  f"{rates.shape}")
        if self.is_perfect or n == 0:
            return ClockedSweeps(np.arange(n, dtype=np.int64), true.copy(), np.zeros(0, dtype=np.int64))
        period = float(np.median(np.diff(true))) if n > 1 else 0.0
        rng = np.random.default_rng([int(seed), 50_001])
        dropped = self._drops(n, rng, rates)
        keep = np.flatnonzero(~dropped).astype(np.int64)
        delay = self._stall_delays(n, period, rng)
        back = np.flatnonzero(rng.random(n) < self.backwards_rate)
        delay[back] += rng.uniform(*self.backwards_late_periods, back.size) * period
        late = {int(i): float(delay[i]) for i in keep[delay[keep] > 0]}
        stamps = host_stamps(true, keep, late, jitter_us=float(self.jitter_us), seed=int(rng.integers(2**32)))
        dup = np.flatnonzero(rng.random(keep.size) < self.duplicate_rate)
        for j in dup[dup > 0]:
            stamps[j] = stamps[j - 1]
        return ClockedSweeps(keep, stamps, np.flatnonzero(dropped).astype(np.int64))

    # ------------------------------------------------------------------ the draws, in a fixed order
    def _drops(self, n: int, rng: np.random.Generator, rates) -> np.ndarray:
        """bool[N]: the sweeps dropped (never sweep 0)."""
        starts = np.flatnonzero(rng.random(n) < self.drop_rate)
        w = np.asarray(self.drop_lengths, dtype=np.float64)
        lengths = rng.choice(np.arange(1, w.size + 1), size=starts.size, p=w / w.sum())
        to_turn = rng.random(starts.size) < self.drop_turn_share
        where = rng.random(starts.size)  # where in the turns a moved event lands
        if rates is not None:
            turning = np.flatnonzero(np.abs(rates) >= self.turn_rate_threshold_rps)
            turning = turning[turning > 0]
            if turning.size:
                moved = turning[np.minimum((where * turning.size).astype(np.int64), turning.size - 1)]
                starts = np.where(to_turn, moved, starts)
        dropped = np.zeros(n, dtype=bool)
        for s, m in zip(starts.tolist(), lengths.tolist()):
            s = max(s, 1)
            if not dropped[s - 1:s + m + 1].any():  # events never touch: each gap is one event's 1-8 sweeps
                dropped[s:s + m] = True
        return dropped

    def _stall_delays(self, n: int, period: float, rng: np.random.Generator) -> np.ndarray:
        """float64[N] each sweep's delay (µs) from the stalls and the draining of their backlogs."""
        delay = np.zeros(n)
        starts = rng.random(n) < self.stall_rate
        lo, hi = self.catch_up_sweeps
        i = 0
        while i < n:
            if not starts[i]:
                i += 1
                continue
            length = min(float(hi), lo * (1.0 - rng.random()) ** (-1.0 / self.catch_up_tail))
            ratio = rng.uniform(*self.catch_up_ratio)
            backlog = length * (1.0 - ratio) * period
            if rng.random() < self.burst_share:
                spacing = rng.uniform(*self.burst_spacing_periods) * period
                gain = period - spacing  # each sweep of the backlog arrives `spacing` after the last
            else:
                gain = (1.0 - ratio) * period
            j = 0
            while i + j < n and backlog - j * gain > 0:
                delay[i + j] = backlog - j * gain
                j += 1
            i += max(j, 1)
        return delay


PRESETS: dict[str, HostClock] = {
    c.name: c
    for c in (
        HostClock(name="perfect"),
        # a sensor's own stamps (Oxford's radar.timestamps, bags stamped by the sensor): sub-ms, nothing late
        HostClock(name="clean", jitter_us=500.0, drop_rate=0.0005, drop_lengths=(0.8, 0.15, 0.05)),
        # fitted to radiate-2019-02-12-edinburgh (docs/time-base.md, "Simulated host clocks"): jitter, stalls and
        # catch-up runs measured there; backwards stamps after another RADIATE drive (issue 50); duplicates and
        # drops at low rates the shared drive cannot rule out (none in its 280 sweeps)
        HostClock(
            name="radiate", jitter_us=6_000.0, stall_rate=0.013, catch_up_ratio=(0.91, 0.95),
            catch_up_sweeps=(10, 150), catch_up_tail=3.0, burst_share=0.0,
            duplicate_rate=0.0005, backwards_rate=0.002, backwards_late_periods=(1.5, 3.5),
            drop_rate=0.002, drop_lengths=(0.4, 0.2, 0.12, 0.08, 0.07, 0.05, 0.04, 0.04),
            drop_turn_share=0.5, turn_rate_threshold_rps=0.15,
        ),
    )
}


def host_clock(name_or_clock) -> HostClock:
    """The preset called ``name_or_clock`` (or ``name_or_clock`` itself if it is a `HostClock`).

    Raises:
        ConfigError: an unknown name, naming the presets.
    """
    if isinstance(name_or_clock, HostClock):
        return name_or_clock
    try:
        return PRESETS[name_or_clock]
    except (KeyError, TypeError):
        raise ConfigError(f"unknown host clock {name_or_clock!r}; choose one of {', '.join(PRESETS)} "
                          "or pass a radar_odom.sim.host_clock.HostClock") from None


# ---------------------------------------------------------------------------------------------- statistics
STATS_QUANTILES = (1, 10, 50, 90, 99)
MAX_CATCH_UP = 300  # intervals searched for a stall's backlog to drain


SPAN = 32  # intervals per span of `span_period_us`


def span_period_us(stamps_us) -> float:
    """The period (µs) as the median over spans of `SPAN` intervals (fewer in a short recording) of each
    span's mean interval: robust to stalls, catch-up runs and drops that touch a minority of the spans."""
    s = np.asarray(stamps_us, dtype=np.int64)
    k = max(1, min(SPAN, (s.size - 1) // 4))
    return float(np.median((s[k:] - s[:-k]) / k))


def interval_stats(stamps_us, period_us: float | None = None, drained_within: float = 0.1) -> dict:
    """Statistics of a recording's stamp intervals, in reception order (the same for real and simulated stamps).

    Args:
        stamps_us: int[K] stamps as written.
        period_us: the sensor's period; default `span_period_us` (the median interval would be biased by
            the catch-up runs: 249.25 ms on the shared drive, whose fitted period is 249.82 ms).
        drained_within: a stall's backlog counts as drained once the stamps are back within this share of a
            period of the line from the stamp before the stall at the period.

    Returns:
        ``intervals`` (K − 1), ``period_ms``, ``p1`` … ``p99`` (interval quantiles, ms), ``long_share``
        (> 1.5 P), ``short_share`` (< 0.5 P), ``negative_share`` (< 0), ``zero_share`` (= 0), ``stalls``
        (long intervals whose backlog drains within `MAX_CATCH_UP` intervals in 2 or more: a catch-up run
        or a burst), ``catch_up_runs`` (their lengths, intervals until drained), ``single_late`` (long
        intervals drained by the next one: a stamp late alone, a backwards pair), ``gaps`` (long intervals
        never drained: dropped sweeps), and ``stalls_per_1000`` (per 1000 stamps).
    """
    s = np.asarray(stamps_us, dtype=np.int64)
    d = np.diff(s).astype(np.float64)
    if d.size == 0:
        raise ConfigError("interval_stats needs at least two stamps")
    p = span_period_us(s) if period_us is None else float(period_us)
    tol = drained_within * p
    runs, single, gaps = [], 0, 0
    for i in np.flatnonzero(d > 1.5 * p).tolist():
        if i > 0 and d[i - 1] < 0.5 * p and d[i - 1] + d[i] - 2 * p <= tol:
            continue  # a stamp early or repeated, the next on time: one short interval, then a long one
        backlog = np.cumsum(d[i:i + 1 + MAX_CATCH_UP] - p)  # the stamps' delay on the line from stamp i
        drained = np.flatnonzero(backlog[1:] <= tol)
        if not drained.size:
            gaps += 1
        elif drained[0] == 0:
            single += 1
        else:
            runs.append(int(drained[0]) + 1)
    q = np.percentile(d, STATS_QUANTILES) / 1e3
    out = {"intervals": int(d.size), "period_ms": p / 1e3}
    out.update({f"p{k}": float(v) for k, v in zip(STATS_QUANTILES, q)})
    out.update(
        long_share=float(np.mean(d > 1.5 * p)), short_share=float(np.mean(d < 0.5 * p)),
        negative_share=float(np.mean(d < 0)), zero_share=float(np.mean(d == 0)),
        stalls=len(runs), catch_up_runs=tuple(runs), single_late=single, gaps=gaps,
        stalls_per_1000=1000.0 * len(runs) / s.size,
    )
    return out
