"""The recording's time base (`radar_odom.io.timebase`) on the shared RADIATE drive and on the hostile cases.

    python benchmarks/time_base.py                          # the fit alone, < 1 s
    git show f18746f:sdk/radar_odom/io/stamps.py > /tmp/old_stamps.py
    python benchmarks/time_base.py --old /tmp/old_stamps.py # beside the retired repair_late_stamps
    python benchmarks/time_base.py --fuzz 4000              # the property test's generator, ≈ 1 min

Rows: the shared city drive (``../shared/data/real/radiate-2019-02-12-edinburgh``, frames 201–480,
read in place), then synthetic stamps with known truth (fresh seeds ≥ 10000, 0.25 s period, host
jitter uniform ±5 ms): (a) a recording that drops every other sweep (its intervals ≈ 0.5 s) but
for three short stretches of single periods, its last 40 sweeps all there (0.25 s apart); (b) one
stamp 170 ms early, 100 sweeps in; (c) late runs like the drive's (263 / 241 / 218 ms late, caught
up at ≈ 20 ms a sweep). Per row: the period found, the stamps moved (beyond the jitter band; the old
repair: any correction), the largest move, and where the truth is known the largest error of the
times against it.
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DRIVE = ROOT.parent / "shared" / "data" / "real" / "radiate-2019-02-12-edinburgh"
PERIOD_US = 250_000.0
T0_US = 1.5e15


def _synthetic(case: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(stamps µs, true times µs) of a hostile case."""
    rng = np.random.default_rng(seed)
    if case == "a":
        k = np.concatenate([np.arange(0, 200, 2), [201, 202], np.arange(204, 400, 2), [401, 402, 403],
                            np.arange(406, 600, 2), [601], np.arange(604, 800, 2), np.arange(800, 840)])
    else:
        k = np.arange(280)
    true = T0_US + k * PERIOD_US
    stamps = true + rng.uniform(-5_000, 5_000, true.size)
    if case == "b":
        stamps[100] -= 170_000
    if case == "c":
        for at, late, catch in ((135, 263_000, 20_000), (203, 241_000, 18_000), (245, 218_000, 16_500)):
            stamps[at:] += np.maximum(late - catch * np.arange(stamps.size - at), 0)
    return np.round(stamps).astype(np.int64), true


def fuzz(trials: int, max_late: float, spacing: int, first: int = 0) -> list[tuple]:
    """The generator of ``tests/test_timebase.py``'s property, outside hypothesis: trial i draws from
    ``default_rng(20000 + i)`` the period (80–300 ms), 60–300 stamps, jitter ≤ 3 % of P, drops (k
    steps of 2–4, probability ≤ 5 %) and up to 3 late runs (0.2–``max_late`` P late, caught up at
    ≤ 15 % of P a sweep, within 15 sweeps), the k-th starting at 20 + k·``spacing`` (0: 20 + k·N/runs),
    and from ``default_rng(30000 + i)`` the rest. Returns (trial, period ms, stamps, error ms) of each
    fit whose k is not the truth's or whose times err by more than jitter + 0.5 % P."""
    from radar_odom.io.timebase import fit_time_base

    failed = []
    for trial in range(first, first + trials):
        r = np.random.default_rng(20_000 + trial)
        period_ms, n, jf, dp, runs = r.uniform(80, 300), int(r.integers(60, 300)), r.uniform(0, 0.03), \
            r.uniform(0, 0.05), int(r.integers(0, 4))
        rng = np.random.default_rng(30_000 + trial)
        p = period_ms * 1e3
        k = np.cumsum(np.where(rng.random(n) < dp, rng.integers(2, 5, n), 1)) - 1
        true = T0_US + k * p
        stamps = true + rng.uniform(-jf * p, jf * p, n)
        for q in range(runs):
            at = 20 + (q * spacing if spacing else q * (n // runs))
            if at + 15 < n:
                late = rng.uniform(0.2, max_late) * p
                length = int(rng.integers(int(np.ceil(late / (0.15 * p))), 16))
                stamps[at:at + length] += late * (1 - np.arange(length) / length)
        stamps = np.round(stamps).astype(np.int64)
        if np.any(np.diff(stamps) <= 0):
            continue
        tb = fit_time_base(stamps)
        err = np.max(np.abs(tb.times_us - true))
        if not np.array_equal(np.diff(tb.sweep_index), np.diff(k)) or err > jf * p + 0.005 * p + 2:
            failed.append((trial, float(period_ms), n, float(err) / 1e3))
    return failed


def _row(name, stamps, true, new, old) -> list[str]:
    tb = new(stamps)
    corr = tb.corrections_us
    err = "" if true is None else f"{np.max(np.abs(tb.times_us - true)) / 1e3:.1f}"
    lines = [f"| {name} | time base | {tb.period_us / 1e3:.2f} | {tb.moved.size} of {stamps.size} "
             f"({tb.late.size} late, {tb.early.size} early; band ±{tb.tolerance_us / 1e3:.1f} ms) | "
             f"{np.max(np.abs(corr)) / 1e3:.0f} | {tb.dropped} | {err} |"]
    if old is not None:
        rep = old(stamps)
        err = "" if true is None else f"{np.max(np.abs(rep.timestamps_us - true)) / 1e3:.1f}"
        moved = int(np.sum(rep.corrections_us != 0))
        lines.append(f"| {name} | old repair | {rep.period_us / 1e3:.2f} | {moved} of {stamps.size} | "
                     f"{np.max(np.abs(rep.corrections_us)) / 1e3:.0f} | | {err} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--drive", type=Path, default=DRIVE)
    ap.add_argument("--old", type=Path, default=None, help="a copy of the retired io/stamps.py to compare with")
    ap.add_argument("--fuzz", type=int, default=0, metavar="N",
                    help="also run N trials of the property test's generator (see fuzz)")
    ap.add_argument("--max-late", type=float, default=0.9, help="--fuzz: the latest run start, in periods")
    ap.add_argument("--spacing", type=int, default=40, help="--fuzz: sweeps between run starts (0: N / runs)")
    args = ap.parse_args(argv)
    from radar_odom.io.timebase import fit_time_base

    if args.fuzz:
        failed = fuzz(args.fuzz, args.max_late, args.spacing)
        print(f"fuzz: {len(failed)} of {args.fuzz} trials failed (late runs ≤ {args.max_late:g} P, "
              f"spacing {args.spacing or 'N / runs'}): {[(t, round(p, 1), n, round(e, 1)) for t, p, n, e in failed]}")

    old = None
    if args.old is not None:
        spec = importlib.util.spec_from_file_location("radar_odom.io._old_stamps", args.old)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod  # its dataclass looks its module up
        spec.loader.exec_module(mod)
        old = mod.repair_late_stamps

    def new(stamps):
        return fit_time_base(stamps, period_hint_us=PERIOD_US)

    lines = ["| stamps | method | period ms | stamps moved | largest move ms | sweeps dropped | "
             "largest error vs truth ms |", "|---|---|---:|---|---:|---:|---:|"]
    if (args.drive / "Navtech_Polar.txt").is_file():
        from radar_odom.io import read_sequence

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            raw = read_sequence(args.drive, repair_stamps=False).timestamps_us
        lines += _row("shared RADIATE drive", raw, None, new, old)
        tb = new(raw)
        iv = np.diff(tb.times_us) / 1e3
        on = np.abs(tb.corrections_us) <= tb.tolerance_us
        print(f"drive: fitted intervals {iv.min():.2f}–{iv.max():.2f} ms (recorded {np.diff(raw).min() / 1e3:.1f}–"
              f"{np.diff(raw).max() / 1e3:.1f}); on-time stamps' |correction| median "
              f"{np.median(np.abs(tb.corrections_us[on])) / 1e3:.1f} ms; late runs start at "
              f"{[int(i) for i in tb.late if i - 1 not in set(tb.late)]}; {tb.summary()}")
    else:
        print(f"{args.drive}: not there; the synthetic rows only", file=sys.stderr)
    for case, seed, name in (("a", 10_020, "(a) every other sweep dropped"), ("b", 10_021, "(b) one early stamp"),
                             ("c", 10_022, "(c) three late runs")):
        stamps, true = _synthetic(case, seed)
        lines += _row(name, stamps, true, new, old)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
