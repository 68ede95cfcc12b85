"""One time base per recording: sweep times on the sensor's period, fitted once from the host's stamps.

A spinning radar sweeps at a fixed period P; a recording host (RADIATE, a ROS driver) stamps each
sweep when it gets it: late by a non-negative delay, with a few ms of jitter, now and then early
(one stamp ahead of its neighbours' rhythm). The model fitted here::

    sweep i happened at  τ_i = t0 + k_i·P + b(k_i),  stamp_i = τ_i + delay_i + jitter_i,  delay_i ≥ 0

with k_i increasing integers (k_{i+1} − k_i − 1 sweeps dropped between them) and b a slow drift
(the sensor's period against the host's clock: a local line over ±`DRIFT_HALF_WINDOW` on-time stamps).

How (`fit_time_base`; every step a pure function below):

1. The period (`fundamental_period_us`): the common interval (`common_interval_us`) or a whole fraction of
   it, P = c/m, the largest that explains the intervals as whole multiples: a fraction is taken
   only where at least `MIN_OFF_HARMONIC` intervals (and 1 % of them, and twice what chance puts
   there) sit on a multiple of c/m that the coarser period misses (a recording that drops every
   other sweep but keeps a few 1-period intervals: c ≈ 0.5 s, P ≈ 0.25 s). Where every interval
   is a multiple of c, the stamps cannot tell P from P/2, P/3, …: `TimeBase.candidate_periods_us`
   lists them and ``period_hint_us`` (the sensor's nominal period, where known) picks the nearest;
   the match may decide the rest. Then refined over spans of 4, 16 and 64 stamps (`refine_period_us`).
2. The on-time phase (`local_phase_us`): stamp times modulo P; on-time stamps share one phase,
   late ones sit after it, dropped sweeps do not move it. The phase is the mode of a window of
   ±`PHASE_HALF_WINDOW` stamps, unwrapped along the recording: a local lattice that follows a
   period a little off (the median interval of the shared drive is 0.7 ms short of its slope).
3. The sweep indices (`assign_sweep_indices`): a shortest path over the few lattice slots each
   stamp could belong to, k strictly increasing. Cost in periods: a late stamp its delay, an early
   one (beyond the jitter band) `EARLY_COST` + how early, a dropped sweep `DROP_COST`. So one early
   stamp costs a few periods and is taken as early, instead of the 18 stamps before it as late by a
   period each; a late run with its catch-up stays late, since calling it on time would make every
   later stamp early; a real drop keeps its gap.
4. The lattice (`fit_lattice_us`): t0 and P by least squares on the on-time stamps (within the
   jitter band), the drift b as a local line through their residuals; steps 3–4 are run
   `FIT_ROUNDS` times, each on the lattice fitted last.
5. The readings it cannot rule out (`slot_path_costs`, `sweep_alternatives`): for every stamp and
   slot, the cheapest whole path through it; a slot within `ALTERNATIVE_MARGIN` of the best is
   listed in `TimeBase.alternatives`. A sweep after a single drop is always one: on time with the
   drop before it, or a period late with the drop after it (the same stamps). The odometer's match
   no longer acts on them (issue 50: the odometer's match decides a step's periods whatever the stamps say).

Every sweep's time is then its lattice time: the host's jitter is gone too; stamps off it by more than
the jitter band (`TimeBase.moved`) are the ones a run reports. Stamps all within `CLEAN_STAMP_US` (5 ms)
of the lattice are a sensor's own and are never moved (their times are the stamps as recorded). Nothing
here depends on the sweeps' content; the shared RADIATE city drive and the hostile cases are in docs/time-base.md.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import SequenceError

MIN_SWEEPS = 4  # fewer stamps cannot tell a late stamp from a slow sensor
# stamps all within this of the fitted lattice are a sensor's own (jitter under 5 ms): kept as recorded
CLEAN_STAMP_US = 5_000
# below this share of stamps within the jitter band of the fitted lattice, no lattice holds them: kept as
# recorded (`as_recorded`; the shared RADIATE drive has 86 % on time, its 39 late stamps in three runs)
MIN_ON_TIME_SHARE = 0.5
AS_RECORDED = "stamps too irregular for a lattice: kept as recorded"  # `TimeBase.period_from` of `as_recorded`
# the finest whole fraction of the common interval considered for the period: finer ones meet a late run's
# catch-up intervals (all alike, a little short of a period) by chance
MAX_DIVISOR = 4
MIN_OFF_HARMONIC = 3  # intervals that a whole fraction of the period must explain and the period not
# the jitter band: 3 σ of a stamp's jitter (from the intervals), at least this (a clean synthetic
# recording has none) and at most a tenth of the period
MIN_TOLERANCE_US = 2_000.0
MAX_TOLERANCE_PERIODS = 0.1
PHASE_HALF_WINDOW = 20  # stamps each side in the on-time phase's mode (10 s at 4 Hz)
DRIFT_HALF_WINDOW = 40  # on-time stamps each side in the drift's local line (20 s at 4 Hz)
EARLY_COST = 2.0  # periods of delay one early stamp is worth (three stamps before it outweigh it)
DROP_COST = 0.5  # periods of delay one dropped sweep is worth
FIT_ROUNDS = 3  # slots then lattice: the first lattice is the local phase's, each next the fitted one
_SLOTS = (-2, -1, 0, 1, 2)  # lattice slots around the nearest one a stamp may take (late ≤ 2.5 P)
# A slot whose cheapest path costs within this many periods of the fit's is a reading the stamps cannot
# rule out: one stamp a whole period late with the drop after it costs 1 period more than an on-time stamp
# with the drop before it (identical stamps), two such stamps 2 more, an early stamp ≥ `EARLY_COST`.
ALTERNATIVE_MARGIN = 1.25


@dataclass(frozen=True)
class TimeBase:
    """Sweep times of a recording fitted on the sensor's period (`fit_time_base`).

    Attributes:
        stamps_us: int64[N] the stamps as recorded.
        times_us: int64[N] the fitted sweep times, ``t0 + k·P + drift`` (µs).
        sweep_index: int64[N] k_i, from 0; ``diff − 1`` sweeps were dropped between two stamps.
        period_us: P, the sensor's period (µs; the mean over the recording; 0.0 where under
            `MIN_SWEEPS` stamps, whose times are then the stamps).
        tolerance_us: the jitter band: a stamp within it of its time is host jitter, not moved.
        candidate_periods_us: P and its whole fractions down to ``P / 3``: the stamps fit each
            equally (every interval a whole multiple); P is the largest, chosen by the stamps or
            by ``period_hint_us`` (`period_from`).
        period_from: "stamps", "hint" (a hint picked a whole fraction of the common interval) or
            "too few stamps".
        alternatives: ((i, (k_i, k_alt, …)), …) the sweeps whose index the stamps cannot tell (the
            fitted k first; `sweep_alternatives`): typically a sweep after a drop, whose stamp may
            instead be a period late with the drop after it (kept for the reader's report: the odometer's
            match decides a step's periods itself, `radar_odom.odometry.match_stage`).
    """

    stamps_us: np.ndarray
    times_us: np.ndarray
    sweep_index: np.ndarray
    period_us: float
    tolerance_us: float
    candidate_periods_us: tuple
    period_from: str = "stamps"
    alternatives: tuple = ()

    @property
    def corrections_us(self) -> np.ndarray:
        """int64[N] ``stamp − time``: > 0 late, < 0 early (within `tolerance_us`: jitter)."""
        return self.stamps_us - self.times_us

    @property
    def moved(self) -> np.ndarray:
        """int64[K] indices of the stamps off their time by more than the jitter band."""
        return np.flatnonzero(np.abs(self.corrections_us) > self.tolerance_us)

    @property
    def late(self) -> np.ndarray:
        """int64[K] indices of the stamps later than their time by more than the jitter band."""
        return np.flatnonzero(self.corrections_us > self.tolerance_us)

    @property
    def early(self) -> np.ndarray:
        """int64[K] indices of the stamps earlier than their time by more than the jitter band."""
        return np.flatnonzero(self.corrections_us < -self.tolerance_us)

    @property
    def dropped(self) -> int:
        """How many sweeps are missing between the first and the last stamp."""
        return int(np.sum(np.diff(self.sweep_index) - 1)) if self.sweep_index.size else 0

    @property
    def period_s(self) -> float | None:
        """P in seconds, or None where too few stamps to tell."""
        return self.period_us / 1e6 if self.period_us > 0 else None

    def summary(self) -> str:
        """One line for a run's notes: the stamps moved (late / early, how far), the sweeps dropped,
        the period and the jitter band; empty where no stamp was moved and none dropped."""
        if self.period_from == AS_RECORDED:
            return (f"sweep stamps too irregular for the sensor's period (most off any {self.period_us / 1e3:.1f} ms "
                    "lattice by more than a host's jitter): kept as recorded; the odometry's match decides")
        if not self.moved.size and not self.dropped and not self.alternatives:
            return ""
        corr = self.corrections_us
        parts = []
        late, early = self.late, self.early
        if late.size:
            runs = int(np.sum(np.diff(np.concatenate([[-2], late])) > 1))
            parts.append(f"{late.size} sweep stamps were late (up to {corr[late].max() / 1e3:.0f} ms, in {runs} "
                         f"run{'s' if runs != 1 else ''})")
        if early.size:
            parts.append(f"{early.size} early (up to {-corr[early].min() / 1e3:.0f} ms)")
        if self.dropped:
            parts.append(f"{self.dropped} sweep{'s' if self.dropped != 1 else ''} dropped (kept as gaps)")
        if self.alternatives:
            n = len(self.alternatives)
            parts.append(f"{n} sweep time{'s' if n != 1 else ''} the stamps cannot place (a dropped sweep before it, "
                         "or its stamp a period late and the drop after it; the odometry's match decides)")
        how = "" if self.period_from == "stamps" else f", {self.period_from}"
        return (f"{', '.join(parts)}; sensor period {self.period_us / 1e3:.2f} ms{how}, host jitter "
                f"±{self.tolerance_us / 1e3:.1f} ms: every sweep time put on the sensor's period")


def check_stamps_us(timestamps_us) -> np.ndarray:
    """int64[N] stamps, or `SequenceError` where they do not increase strictly."""
    t = np.asarray(timestamps_us, dtype=np.int64).reshape(-1)
    if not np.all(np.diff(t) > 0):
        raise SequenceError("sweep stamps must increase strictly; sort the sweeps by time or drop the duplicates")
    return t


def interval_jitter_us(intervals_us: np.ndarray, period_us: float) -> float:
    """Robust σ (µs) of the intervals about their nearest whole multiple of ``period_us`` (those
    within a fifth of a period of one: late-run and early-stamp intervals left out)."""
    n = np.maximum(np.round(intervals_us / period_us), 1.0)
    r = intervals_us - n * period_us
    r = r[np.abs(r) < 0.2 * period_us]
    if r.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def tolerance_us(intervals_us: np.ndarray, period_us: float) -> float:
    """The jitter band (µs): 3 σ of one stamp's jitter (an interval's σ / √2)."""
    sigma = interval_jitter_us(intervals_us, period_us) / math.sqrt(2.0)
    return float(min(max(3.0 * sigma, MIN_TOLERANCE_US), MAX_TOLERANCE_PERIODS * period_us))


def common_interval_us(intervals_us: np.ndarray, width: float = 0.05) -> float:
    """The most common interval (µs): the median of the largest cluster of intervals within
    ±``width`` of one of them. Not the median of all: with as many 2-period intervals as 1-period
    ones that falls between the two."""
    d = np.sort(np.asarray(intervals_us, dtype=np.float64))
    count = np.searchsorted(d, d * (1 + width), side="right") - np.searchsorted(d, d * (1 - width), side="left")
    best = d[int(np.argmax(count))]
    return float(np.median(d[np.abs(d - best) <= width * best]))


def fundamental_period_us(intervals_us, period_hint_us: float | None = None) -> tuple[float, tuple, str]:
    """(P µs, candidates µs, how chosen): the largest whole fraction c/m (m ≤ `MAX_DIVISOR`) of the
    common interval c that explains the intervals as whole multiples (module docstring, step 1).

    ``period_hint_us``: the sensor's nominal period where known: among the fractions that explain
    every interval the common one does, the nearest to it (the stamps cannot tell those apart).
    """
    d = np.asarray(intervals_us, dtype=np.float64)
    c = common_interval_us(d)
    tol = tolerance_us(d, c)

    def explained(p):
        n = np.maximum(np.round(d / p), 1.0)
        return np.abs(d - n * p) <= tol, n

    best_m, best_ok = 1, explained(c)[0]
    for m in range(2, MAX_DIVISOR + 1):
        p = c / m
        if p < 4.0 * tol:  # a band of ±tol then catches a quarter of any intervals: no evidence
            break
        ok, _ = explained(p)
        new = int(np.sum(ok & ~best_ok))
        # twice what chance gives: a band of ±tol catches 2·tol/p of the intervals the coarser period misses
        chance = np.sum(~best_ok) * 2.0 * tol / p
        if new >= max(MIN_OFF_HARMONIC, 0.01 * d.size, 2.0 * chance):
            best_m, best_ok = m, ok
    how = "stamps"
    if period_hint_us is not None and period_hint_us > 0:
        # the whole fractions of the chosen period explain every interval it does: the stamps cannot choose
        m_hint = max(1, round((c / best_m) / float(period_hint_us)))
        if m_hint > 1 and (c / best_m / m_hint) >= 4.0 * tol:
            best_m *= m_hint
            how = f"the sensor's nominal {period_hint_us / 1e3:.0f} ms picked it among the whole fractions"
    p = c / best_m
    ok, n = explained(p)
    # refined on the intervals it explains (late runs and early stamps left out): the median, since a
    # late run's catch-up intervals (a little short, all alike) are explained too and a sum would follow them
    p = float(np.median(d[ok] / n[ok])) if ok.any() else p
    candidates = tuple(p / j for j in range(1, 4) if p / j >= 4.0 * tol)
    return p, candidates, how


def refine_period_us(stamps_us: np.ndarray, period_us: float, spans=(4, 16, 64)) -> float:
    """The period (µs) refined over ever longer spans of stamps: the median over i of
    ``(t[i+b] − t[i]) / round((t[i+b] − t[i]) / P)`` for b = 4, 16, 64 (each as long as the recording
    allows). The median of single intervals follows a late run's catch-up intervals, all alike
    (2.5 % short on a synthetic recording with a third of its stamps late); over a span of b
    sweeps a late end errs by its delay / b, and the median leaves out the spans a late end
    shifts by a whole period. Dropped sweeps inside a span are counted by the rounding."""
    t = stamps_us.astype(np.float64)
    p = float(period_us)
    for b in spans:
        if b > t.size // 2:
            break
        span = t[b:] - t[:-b]
        count = np.maximum(np.round(span / p), 1.0)
        p = float(np.median(span / count))
    return p


def local_phase_us(stamps_us: np.ndarray, period_us: float, tol_us: float,
                   half_window: int = PHASE_HALF_WINDOW) -> np.ndarray:
    """float64[N] the on-time phase at each stamp (µs since the first stamp, unwrapped): the mode of
    the stamps' phases modulo ``period_us`` over ±``half_window`` stamps (on-time stamps agree on it,
    late ones scatter after it), refined as the mean of the phases within ``tol_us`` of it."""
    t = (stamps_us - stamps_us[0]).astype(np.float64)
    phase = np.mod(t, period_us)
    n = t.size
    w = min(int(half_window), n - 1)
    idx = np.clip(np.arange(n)[:, None] + np.arange(-w, w + 1)[None, :], 0, n - 1)
    out = np.empty(n)
    for lo in range(0, n, 1024):  # chunks bound the memory to 1024 × (2w+1)²
        ph = phase[idx[lo:lo + 1024]]  # [c, W]
        diff = ph[:, None, :] - ph[:, :, None]  # [c, W, W] from each candidate to each phase
        diff -= period_us * np.round(diff / period_us)
        score = np.maximum(0.0, 1.0 - np.abs(diff) / (2.0 * tol_us)).sum(axis=2)
        best = np.argmax(score, axis=1)
        near = diff[np.arange(len(best)), best]  # [c, W]
        inside = np.abs(near) <= tol_us
        centre = ph[np.arange(len(best)), best]
        out[lo:lo + 1024] = centre + np.sum(np.where(inside, near, 0.0), axis=1) / np.maximum(inside.sum(axis=1), 1)
    return np.unwrap(out, period=period_us)


def _slot_nodes(stamps_us: np.ndarray, base_us: np.ndarray, period_us: float, tol_us: float):
    """(int64[N, S] the lattice slots each stamp may take, float list[N][S] their costs in periods:
    a late stamp its delay, an early one beyond the band `EARLY_COST` + how early)."""
    u = (stamps_us.astype(np.float64) - base_us) / period_us
    nearest = np.round(u).astype(np.int64)
    slots = nearest[:, None] + np.array(_SLOTS, dtype=np.int64)[None, :]  # [N, S]
    offset = u[:, None] - slots  # periods, > 0 late
    tol = tol_us / period_us
    return slots, np.where(offset >= -tol, np.maximum(offset, 0.0), EARLY_COST - offset).tolist()


def _forward_costs(slots: np.ndarray, node: list, period_us: float) -> tuple[list, np.ndarray]:
    """(float list[N][S] the cheapest path cost up to and including each stamp's slot, int64[N, S]
    the previous stamp's slot on that path): k strictly increasing, `DROP_COST` per skipped slot."""
    slots_l = slots.tolist()
    n, s = slots.shape
    acc = [list(node[0])]
    back = np.zeros((n, s), dtype=np.int64)
    inf = math.inf
    for i in range(1, n):
        prev, cur, last, new = slots_l[i - 1], slots_l[i], acc[-1], [inf] * s
        row = back[i]
        for b in range(s):
            kb, best, arg = cur[b], inf, 0
            for a in range(s):
                step = kb - prev[a]
                if step >= 1 and last[a] < inf:
                    c = last[a] + DROP_COST * (step - 1)
                    if c < best:
                        best, arg = c, a
            new[b] = best + node[i][b]
            row[b] = arg
        acc.append(new)
        if min(new) == inf:
            raise SequenceError(f"sweep stamps {i - 1}–{i} cannot be sweeps of a sensor with a period of "
                                f"{period_us / 1e3:.1f} ms (too many stamps within one period); check the "
                                "recording's time file")
    return acc, back


def assign_sweep_indices(stamps_us: np.ndarray, base_us: np.ndarray, period_us: float, tol_us: float) -> np.ndarray:
    """int64[N] k_i: each stamp's slot on the lattice ``base_us[i] + k·period_us`` (the lattice's
    slot 0 as seen from stamp i; k not shifted to start at 0), strictly increasing, by the cheapest
    path (module docstring, step 3).

    Raises:
        SequenceError: stamps that no increasing slots fit (more than a few within one period).
    """
    slots, node = _slot_nodes(stamps_us, base_us, period_us, tol_us)
    acc, back = _forward_costs(slots, node, period_us)
    n = slots.shape[0]
    k = np.empty(n, dtype=np.int64)
    b = int(np.argmin(acc[-1]))
    for i in range(n - 1, -1, -1):
        k[i] = slots[i, b]
        b = int(back[i, b])
    return k


def slot_path_costs(stamps_us: np.ndarray, base_us: np.ndarray, period_us: float,
                    tol_us: float) -> tuple[np.ndarray, np.ndarray]:
    """(int64[N, S] slots, float64[N, S] costs): for each stamp and each lattice slot it may take,
    the cost (periods) of the cheapest whole path of `assign_sweep_indices` through that slot. The
    chosen path's slots cost the minimum; a slot within `ALTERNATIVE_MARGIN` of it is a reading of
    the stamps nearly as good (`sweep_alternatives`).

    The cost after a slot is the same forward pass run on the stamps reversed (slots negated: k still
    increases, and a skipped slot costs the same either way)."""
    slots, node = _slot_nodes(stamps_us, base_us, period_us, tol_us)
    fwd, _ = _forward_costs(slots, node, period_us)
    bwd, _ = _forward_costs(-slots[::-1], node[::-1], period_us)
    # each path's cost counts its own node once: forward and backward both include it
    cost = np.asarray(fwd) + np.asarray(bwd[::-1]) - np.asarray(node)
    return slots, cost


def sweep_alternatives(slots: np.ndarray, cost: np.ndarray, k: np.ndarray,
                       margin: float = ALTERNATIVE_MARGIN) -> tuple:
    """((i, (k_i, k_alt, …)), …): the stamps the fit cannot place, each with its fitted slot first and
    the other slots whose cheapest path costs within ``margin`` periods of the best (from
    `slot_path_costs`; ``k`` the fitted slots, in the same numbering as ``slots``)."""
    best = float(cost.min(axis=1).min()) if cost.size else 0.0
    out = []
    for i in np.flatnonzero(np.sum(cost <= best + margin, axis=1) > 1):
        alt = sorted({int(s) for s, c in zip(slots[i], cost[i]) if c <= best + margin and s != k[i]},
                     key=lambda s: abs(s - int(k[i])))
        if alt:
            out.append((int(i), (int(k[i]), *alt)))
    return tuple(out)


def local_line(x: np.ndarray, y: np.ndarray, half_window: int) -> np.ndarray:
    """float64[N] each y[i] smoothed: the least-squares line through its ±``half_window`` neighbours
    (fewer at the ends), evaluated at x[i]. A line, not a mean: at the ends of a recording a
    drifting clock would otherwise be followed a window late."""
    n = x.size
    xc = x - x.mean()
    cs = [np.concatenate([[0.0], np.cumsum(v)]) for v in (np.ones(n), xc, y, xc * xc, xc * y)]
    i = np.arange(n)
    lo, hi = np.maximum(0, i - half_window), np.minimum(n, i + half_window + 1)
    s0, sx, sy, sxx, sxy = (c[hi] - c[lo] for c in cs)
    var = sxx * s0 - sx * sx
    slope = np.where(var > 0, (sxy * s0 - sx * sy) / np.where(var > 0, var, 1.0), 0.0)
    return (sy - slope * sx) / s0 + slope * xc


def fit_lattice_us(stamps_us: np.ndarray, k: np.ndarray, on_time: np.ndarray,
                   half_window: int = DRIFT_HALF_WINDOW) -> tuple[np.ndarray, float]:
    """(float64[N] lattice times µs, P µs): ``t0 + k·P`` by least squares on the ``on_time`` stamps,
    plus their residuals' drift (`local_line` over ±``half_window`` of them), interpolated in k for
    the others."""
    t = (stamps_us - stamps_us[0]).astype(np.float64)
    ko, to = k[on_time].astype(np.float64), t[on_time]
    slope, t0 = np.polyfit(ko, to, 1)
    drift = local_line(ko, to - (t0 + slope * ko), half_window)
    lattice = t0 + slope * k + np.interp(k.astype(np.float64), ko, drift)
    return lattice + float(stamps_us[0]), float(slope)


def check_period_hint_us(value) -> float | None:
    """``period_hint_us`` as a float, or None; `ConfigError` for anything but a positive finite number (a string,
    a bool, NaN, ∞, 0 or less), which would otherwise fail deep inside the fit (a TypeError) or be dropped."""
    from ..errors import ConfigError

    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) or not (
            math.isfinite(value) and value > 0):
        raise ConfigError(f"period_hint_us must be the sensor's period in microseconds, a positive number (e.g. "
                          f"250000.0 for 4 Hz), or None; got {value!r}")
    return float(value)


def as_recorded(t: np.ndarray, period_us: float, tol_us: float, candidates=()) -> TimeBase:
    """The time base that keeps stamps ``t`` (int64[N], µs) as recorded: too irregular for a lattice (most of
    them off any lattice by more than the jitter band, e.g. 100 ms of host jitter), where a fit would move
    them further from the truth than they are (issue 50: 254.2 ms fitted for 249.8 ms, times 0.24 s off).
    The stamps cannot say which sweeps were dropped either: one index a sweep (the odometer's match decides)."""
    return TimeBase(t.copy(), t.copy(), np.arange(t.size, dtype=np.int64), float(period_us), float(tol_us),
                    tuple(period_us / j for j in range(1, len(candidates) + 1)) or (float(period_us),),
                    AS_RECORDED)


def fit_time_base(timestamps_us, period_hint_us: float | None = None) -> TimeBase:
    """The recording's sweep times on the sensor's period, from its stamps (module docstring).

    Args:
        timestamps_us: int[N] sweep stamps (µs), strictly increasing.
        period_hint_us: the sensor's nominal period (µs) where known: picks among the whole
            fractions of the common interval that the stamps cannot tell apart (a recording where
            every interval is two periods); None: the largest.

    Returns:
        `TimeBase`; times = stamps where fewer than `MIN_SWEEPS`.

    Raises:
        SequenceError: stamps that do not increase, or that no sensor period fits.
        ConfigError: a ``period_hint_us`` that is not a positive finite number (``'250000'``, NaN, 0).
    """
    period_hint_us = check_period_hint_us(period_hint_us)
    t = check_stamps_us(timestamps_us)
    if t.size < MIN_SWEEPS:
        return TimeBase(t.copy(), t.copy(), np.arange(t.size, dtype=np.int64), 0.0, 0.0, (), "too few stamps")
    intervals = np.diff(t).astype(np.float64)
    period, candidates, how = fundamental_period_us(intervals, period_hint_us)
    period = refine_period_us(t, period)
    tol = tolerance_us(intervals, period)
    base = t[0] + local_phase_us(t, period, tol)
    try:
        for _ in range(FIT_ROUNDS):
            k = assign_sweep_indices(t, base, period, tol)
            # on time: within the band of the lattice the slots were taken on (first: the local phase's)
            on_time = np.abs(t - (base + k * period)) <= tol
            if on_time.sum() < 2:
                on_time = np.ones_like(on_time)
            lattice, period = fit_lattice_us(t, k, on_time)
            base = lattice - k * period
    except SequenceError:  # no lattice of that period holds the stamps (jitter of a period's order)
        return as_recorded(t, period, tol, candidates)
    if np.mean(np.abs(t - lattice) <= tol) < MIN_ON_TIME_SHARE:
        return as_recorded(t, period, tol, candidates)
    times = np.round(lattice).astype(np.int64)
    if np.all(np.abs(t - times) <= CLEAN_STAMP_US):
        # a sensor's own stamps (Oxford, a bag stamped by the driver): nothing late or early beyond a few ms,
        # so nothing to put back; the stamps are the times as recorded (issue 50: clean stamps never move)
        times = t.copy()
    # the readings nearly as cheap as the fit's, on the lattice fitted last (its slots number as k)
    slots, cost = slot_path_costs(t, lattice - k * period, period, tol)
    alternatives = tuple((i, tuple(int(s) - int(k[0]) for s in ks)) for i, ks in sweep_alternatives(slots, cost, k))
    return TimeBase(t.copy(), times, k - k[0], float(period), float(tol),
                    tuple(period / j for j in range(1, len(candidates) + 1)) or (float(period),), how, alternatives)
